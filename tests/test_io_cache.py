"""The on-disk bake cache (hr_addon/io/cache.py, no bpy)."""

import json
import os

import numpy as np
import pytest

from hr_addon.io.cache import (
    MARKER,
    CacheError,
    CacheReader,
    CacheWriter,
    check_writable,
    owned_files,
    recover,
    remove_stale_temp,
)

OBJS = {"a": {"mesh": "a", "count": 3}, "b": {"mesh": "b", "count": 2}}


def _arrays(v):
    return {"a": np.full((3, 3), v, np.float32), "b": np.full((2, 3), v, np.float32)}


def _bake(d, frames, value, sig="s", objects=OBJS, reuse_after=None):
    w = CacheWriter(d, objects, "CORNER", sig)
    prev = None
    for f in frames:
        if reuse_after is not None and prev is not None and f > reuse_after:
            w.reuse(f, prev)
        else:
            w.write(f, _arrays(value(f)))
        prev = f
    w.commit()
    return w


def test_write_read_roundtrip(tmp_path):
    d = tmp_path / "cache" / "scene"
    _bake(d, range(1, 6), lambda f: f, reuse_after=3)
    r = CacheReader(d)
    assert r.frame_range == (1, 5)
    assert r.domain == "CORNER"
    a = r.load(2)["a"]
    assert a.shape == (3, 4) and a.dtype == np.float32
    assert np.all(a[:, :3] == 2) and np.all(a[:, 3] == 1)
    assert np.all(r.load(5)["b"][:, :3] == 3)  # frames 4, 5 reuse frame 3's file
    assert r.frames[5] == r.frames[3]
    assert len(list(d.glob("*.npz"))) == 3
    # Outside the baked range: held / clamped.
    assert np.all(r.load(100)["a"][:, :3] == 3) and np.all(r.load(-7)["a"][:, :3] == 1)
    # No temporary directories or files are left behind.
    assert sorted(p.name for p in d.parent.iterdir()) == ["scene"]
    assert [p.name for p in d.iterdir() if p.name.startswith(".")] == [MARKER]


def test_loaded_arrays_are_buffers_blenders_foreach_set_takes_whole(tmp_path):
    """Members at unaligned offsets in the file (names of 1-3 letters) load as aligned, C-contiguous
    float32 arrays exporting buffer format 'f': the only one Blender's foreach_set copies whole
    (an unaligned view exports '=f', which it reads element by element), with the values written."""
    objects = {n: {"mesh": n, "count": 2 + len(n)} for n in ("a", "bb", "ccc")}
    rng = np.random.default_rng(3)
    arrays = {n: rng.random((info["count"], 3)).astype(np.float32) for n, info in objects.items()}
    w = CacheWriter(tmp_path / "c", objects, "CORNER", "s")
    w.write(1, arrays)
    w.commit()
    loaded = CacheReader(tmp_path / "c").load(1)
    for n, a in loaded.items():
        assert a.flags.aligned and a.flags.c_contiguous and memoryview(a).format == "f", n
        assert np.array_equal(a[:, :3], arrays[n]) and np.all(a[:, 3] == 1)


@pytest.mark.parametrize("zip64", [False, True])
def test_frame_file_is_what_np_savez_writes(tmp_path, monkeypatch, zip64):
    """write_npz's members hold the bytes np.savez writes for the same arrays (names with any
    characters, empty arrays, shared and odd shapes), the zip's CRCs check out, the comment is
    kept; zip64: the zipfile path beyond ZIP32 (here lowered to two members)."""
    import io
    import zipfile

    from hr_addon.io import cache

    if zip64:
        monkeypatch.setattr(cache, "ZIP32", (2, cache.ZIP32[1]))
    rng = np.random.default_rng(1)
    arrays = {
        name: np.ascontiguousarray(rng.random((n, 4)), np.float32)
        for name, n in [("Wall", 7), ("book.001", 7), ("Übung 2 / ünïcødé", 3), ("empty", 0), ("big", 4096)]
    }
    path = tmp_path / "f.npz"
    cache.write_frame(path, arrays, "id1")
    ref = io.BytesIO()
    np.savez(ref, **arrays)
    with zipfile.ZipFile(path) as z, zipfile.ZipFile(ref) as r:
        assert z.testzip() is None and z.comment == b"hr_radiosity bake id1"
        assert z.namelist() == r.namelist()
        for name in r.namelist():
            assert z.read(name) == r.read(name), name
    with np.load(path) as z:
        assert sorted(z.files) == sorted(arrays)
        assert all(np.array_equal(z[k], a) for k, a in arrays.items())
    assert cache.npz_problem(path, {k: {"count": len(a)} for k, a in arrays.items()}, "id1") == ""


@pytest.mark.parametrize("writer", ["write_frame", "savez", "savez_compressed"])
def test_frame_read_is_what_np_load_reads(tmp_path, writer):
    """read_npz gives np.load's arrays (names, dtypes, shapes, Fortran order, values) and the zip
    comment, for our frame files and np.savez's (stored, zip64 headers) or compressed ones; a flipped
    byte in an array's data is refused (CRC-32), as np.load refuses it."""
    import zipfile

    from hr_addon.io import cache

    rng = np.random.default_rng(2)
    arrays = {
        "Wall": rng.random((5, 4)).astype(np.float32),
        "Übung": np.zeros((0, 4), np.float32),
        "b": rng.random((300, 4)).astype(np.float32),
    }
    path = tmp_path / "f.npz"
    if writer == "write_frame":
        cache.write_frame(path, arrays, "id2")
    else:
        arrays["f64 fortran"] = np.asfortranarray(rng.random((3, 7)))
        getattr(np, writer)(path, **arrays)
    got, comment = cache.read_npz(path)
    assert comment == (b"hr_radiosity bake id2" if writer == "write_frame" else b"")
    with np.load(path) as ref:
        assert sorted(got) == sorted(ref.files)
        for k in ref.files:
            assert got[k].dtype == ref[k].dtype and got[k].shape == ref[k].shape
            assert np.array_equal(got[k], ref[k])
            assert got[k].flags.writeable and got[k].flags.f_contiguous == ref[k].flags.f_contiguous
    if writer == "savez_compressed":
        return
    raw = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("b.npy")
    at = info.header_offset
    raw[at + 30 + len("b.npy") + int.from_bytes(raw[at + 28 : at + 30], "little") + 200] ^= 1  # b's values
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="CRC"):
        cache.read_npz(path)
    with pytest.raises(zipfile.BadZipFile):
        np.load(path)["b"]


def test_abort_keeps_previous(tmp_path):
    d = tmp_path / "scene"
    _bake(d, [1, 2], lambda f: 10)
    w = CacheWriter(d, OBJS, "CORNER", "s")
    w.write(1, _arrays(99))
    w.abort()
    assert np.all(CacheReader(d).load(1)["a"][:, :3] == 10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


def test_split_bakes_merge(tmp_path):
    one, two = tmp_path / "one" / "s", tmp_path / "two" / "s"
    _bake(one, range(1, 11), lambda f: f // 3)
    _bake(two, range(1, 6), lambda f: f // 3)
    w = _bake(two, range(6, 11), lambda f: f // 3)
    assert w.kept == 5
    r1, r2 = CacheReader(one), CacheReader(two)
    assert sorted(r1.frames) == sorted(r2.frames) == list(range(1, 11))
    for f in range(1, 11):
        for k in ("a", "b"):
            assert np.array_equal(r1.load(f)[k], r2.load(f)[k])


def test_rebake_subrange_keeps_shared_files_consistent(tmp_path):
    d = tmp_path / "s"
    _bake(d, range(1, 11), lambda f: 1, reuse_after=1)  # every frame points at frame_000001
    _bake(d, range(1, 4), lambda f: 7)  # re-bake 1-3 with other values
    r = CacheReader(d)
    assert [r.load(f)["a"][0, 0] for f in range(1, 11)] == [7] * 3 + [1] * 7


def test_other_settings_discard_previous_frames(tmp_path):
    d = tmp_path / "s"
    _bake(d, range(1, 6), lambda f: 1, sig="old")
    w = _bake(d, range(6, 8), lambda f: 2, sig="new")
    assert w.kept == 0 and w.messages
    assert sorted(CacheReader(d).frames) == [6, 7]


def test_missing_and_corrupt(tmp_path):
    with pytest.raises(CacheError, match="No radiosity cache"):
        CacheReader(tmp_path / "nothing")
    d = tmp_path / "s"
    _bake(d, [1, 2], lambda f: f)
    (d / "manifest.json").write_text("{not json")
    with pytest.raises(CacheError, match="Corrupt radiosity cache manifest"):
        CacheReader(d)
    _bake(d, [1, 2], lambda f: f)
    r = CacheReader(d)
    (d / r.frames[2]).write_bytes(b"garbage")
    with pytest.raises(CacheError, match="Corrupt radiosity cache file"):
        r.load(2)
    os.remove(d / r.frames[1])
    with pytest.raises(CacheError, match="missing"):
        r.load(1)
    m = json.loads((d / "manifest.json").read_text())
    m["objects"]["a"]["count"] = 5
    (d / "manifest.json").write_text(json.dumps(m))
    (d / "frame_000001.npz").write_bytes(b"")
    _bake(d, [1], lambda f: 1)
    m["frames"] = {"1": "frame_000001.npz"}
    (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CacheError, match="bad array"):
        CacheReader(d).load(1)


def test_recover_after_interrupted_swap(tmp_path):
    d = tmp_path / "s"
    _bake(d, [1], lambda f: 3)
    os.replace(d, tmp_path / ".s.old-1-2")  # crash between the two renames of commit()
    assert recover(d)
    assert np.all(CacheReader(d).load(1)["a"][:, :3] == 3)


# ---------------------------------------------------------------------------- never lose a user's files


def _user_files(d):
    (d / "sub").mkdir(parents=True)
    (d / "notes.txt").write_text("mine")
    (d / "sub" / "y.txt").write_text("also mine")


def _tree(d):
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


def test_folder_with_foreign_files_is_refused_and_kept(tmp_path):
    """A bake deleted everything in the folder it was pointed at (issue 18)."""
    d = tmp_path / "textures"
    _user_files(d)
    before = _tree(d)
    for attempt in (lambda: check_writable(d), lambda: CacheWriter(d, OBJS, "CORNER", "s")):
        with pytest.raises(CacheError, match=r"holds files no radiosity bake wrote \(notes.txt, sub\)") as e:
            attempt()
        assert str(d) in str(e.value)
    assert _tree(d) == before and (d / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["textures"]  # no temporary folder left


def test_plain_file_in_the_way_is_refused_and_kept(tmp_path):
    f = tmp_path / "cache"
    f.write_text("a file")
    with pytest.raises(CacheError, match="is a file, not a folder") as e:
        CacheWriter(f, OBJS, "CORNER", "s")
    assert str(f) in str(e.value) and f.read_text() == "a file"


def test_unwritable_folder_names_the_cache_folder(tmp_path):
    with pytest.raises(CacheError, match="Cannot write the cache folder '/proc/x'"):
        check_writable("/proc/x")


def test_empty_folder_is_used(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    _bake(d, [1], lambda f: 1)
    assert sorted(CacheReader(d).frames) == [1]


def test_rebake_deletes_only_what_a_bake_wrote(tmp_path):
    """Files a user put into a cache folder survive every later bake, and a bake that discards the
    previous frames deletes their files."""
    d = tmp_path / "s"
    _bake(d, range(1, 4), lambda f: f)
    _user_files(d)
    (d / "textures").mkdir()
    (d / "textures" / "wood.png").write_bytes(b"png")
    _bake(d, [7], lambda f: 7, sig="other")  # other settings: frames 1-3 discarded
    r = CacheReader(d)
    assert sorted(r.frames) == [7]
    assert (d / "notes.txt").read_text() == "mine" and (d / "sub" / "y.txt").read_text() == "also mine"
    assert (d / "textures" / "wood.png").read_bytes() == b"png"
    assert sorted(p.name for p in d.glob("*.npz")) == [r.frames[7]]
    assert owned_files(d) == {MARKER, "manifest.json", r.frames[7]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


def test_cache_of_an_earlier_version_without_marker_is_ours(tmp_path):
    d = tmp_path / "s"
    _bake(d, [1, 2], lambda f: f)
    (d / MARKER).unlink()
    m = json.loads((d / "manifest.json").read_text())
    del m["files"]
    (d / "manifest.json").write_text(json.dumps(m))
    (d / "readme.txt").write_text("mine")
    _bake(d, [3], lambda f: 3, sig="other")
    assert sorted(CacheReader(d).frames) == [3] and (d / "readme.txt").read_text() == "mine"
    assert not (d / "frame_000001.npz").exists()


def test_swapped_out_cache_of_a_killed_bake_gives_user_files_back(tmp_path):
    d = tmp_path / "s"
    _bake(d, [1], lambda f: 1)
    (d / "notes.txt").write_text("mine")
    old = tmp_path / ".s.old-999999999-1"  # a crash after the swap, before the old folder went
    os.replace(d, old)
    _bake(tmp_path / "fresh", [1], lambda f: 2)
    os.replace(tmp_path / "fresh", d)
    assert remove_stale_temp(d) == [old]
    assert (d / "notes.txt").read_text() == "mine" and not old.exists()


def test_stale_temporary_folder_with_foreign_files_is_kept(tmp_path):
    d = tmp_path / "s"
    odd = tmp_path / ".s.baking-999999999-1"  # named like ours, holds something else
    odd.mkdir()
    (odd / "diary.txt").write_text("mine")
    assert remove_stale_temp(d) == [] and (odd / "diary.txt").exists()


@pytest.mark.parametrize("name", ["../../x.npz", "/etc/passwd", "sub/frame_000001.npz"])
def test_manifest_frame_names_stay_inside_the_cache_folder(tmp_path, name):
    d = tmp_path / "s"
    _bake(d, [1], lambda f: 1)
    m = json.loads((d / "manifest.json").read_text())
    m["frames"]["1"] = name
    (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CacheError, match="frame file name"):
        CacheReader(d)


def test_manifest_with_a_bad_domain_is_named(tmp_path):
    d = tmp_path / "s"
    _bake(d, [1], lambda f: 1)
    m = json.loads((d / "manifest.json").read_text())
    m["domain"] = 5
    (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(CacheError, match="domain 5"):
        CacheReader(d)


# ---------------------------------------------------------------------------- frames bound to their bake


def test_frame_copied_from_another_bake_is_named(tmp_path):
    """Two bakes of objects with the same names: a frame file of one copied into the other is
    refused by name (not played back silently), and counts as damaged for the next bake."""
    a, b = tmp_path / "a", tmp_path / "b"
    _bake(a, [1, 2], lambda f: 1)
    _bake(b, [1, 2], lambda f: 5)
    ra = CacheReader(a)
    assert ra.manifest["bake_id"] != CacheReader(b).manifest["bake_id"]
    assert set(ra.load(1)) == {"a", "b"}  # the id is not an object's array
    with np.load(a / "frame_000001.npz") as z:
        assert sorted(z.files) == ["a", "b"]  # other readers of the file see the objects only
    (a / "frame_000002.npz").write_bytes((b / "frame_000002.npz").read_bytes())
    with pytest.raises(CacheError, match=r"frame_000002\.npz' belongs to another bake"):
        CacheReader(a).load(2)
    assert np.all(CacheReader(a).load(1)["a"][:, :3] == 1)
    # A frame file without an id (an older version's) in a cache with ids: not this bake's either.
    np.savez(a / "frame_000001.npz", a=np.zeros((3, 4), np.float32), b=np.zeros((2, 4), np.float32))
    with pytest.raises(CacheError, match=r"frame_000001\.npz' belongs to another bake"):
        CacheReader(a).load(1)
    # The next bake of another range re-bakes both instead of keeping them.
    w = CacheWriter(a, OBJS, "CORNER", "s")
    damaged = w.damaged_frames({3})
    assert sorted(damaged) == [1, 2] and all("belongs to another bake" in v for v in damaged.values())
    w.abort()


def test_frames_kept_from_the_previous_bake_keep_their_id(tmp_path):
    d = tmp_path / "s"
    w1 = _bake(d, [1, 2, 3], lambda f: f)
    w2 = _bake(d, [3, 4], lambda f: 10 * f)  # keeps frames 1-2 of the first bake
    assert w2.kept == 2 and w1.bake_id != w2.bake_id
    r = CacheReader(d)
    assert r.manifest["bake_id"] == w2.bake_id
    assert r.frame_ids[r.frames[1]] == w1.bake_id and r.frame_ids[r.frames[4]] == w2.bake_id
    assert [r.load(f)["a"][0, 0] for f in (1, 2, 3, 4)] == [1, 2, 30, 40]
    w3 = _bake(d, [5], lambda f: 0)  # kept twice: still the first bake's id, still readable
    r = CacheReader(d)
    assert w3.kept == 4 and r.frame_ids[r.frames[1]] == w1.bake_id
    assert [r.load(f)["a"][0, 0] for f in (1, 2, 3, 4, 5)] == [1, 2, 30, 40, 0]
    assert CacheWriter(d, OBJS, "CORNER", "s").damaged_frames({5}) == {}


def test_cache_without_bake_ids_stays_readable(tmp_path):
    """Caches of versions before bake ids: no id in the manifest or the frames."""
    d = tmp_path / "s"
    _bake(d, [1, 2], lambda f: f)
    m = json.loads((d / "manifest.json").read_text())
    del m["bake_id"], m["frame_ids"]
    (d / "manifest.json").write_text(json.dumps(m))
    for f in (1, 2):
        np.savez(d / f"frame_00000{f}.npz", a=np.full((3, 4), f, np.float32), b=np.ones((2, 4), np.float32))
    r = CacheReader(d)
    assert r.frame_ids == {} and r.load(2)["a"][0, 0] == 2
    w = _bake(d, [3], lambda f: 3)  # its frames are kept by a new bake, and read without a check
    r = CacheReader(d)
    assert w.kept == 2 and [r.load(f)["a"][0, 0] for f in (1, 2, 3)] == [1, 2, 3]
