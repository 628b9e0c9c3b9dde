"""The host-visibility segments kept beside the precompute across bakes, and the stores' trim
(io/precompute.py keep / load_kept, core/gather/hostvis.py kept / restore_kept / trim; docs/events.md
session 30 hvkeep). What is kept is speed only: every output here is compared bit for bit.

No bpy. The scene: the Cornell box's precompute (draft, a LoopGather with two levels), a light
shape on the back wall moved over three frames (a bake's events)."""

import shutil
import zipfile

import numpy as np
import pytest

from hr_testing import scenes
from hr_testing import shapes as S
from hr_addon.core.events import DynamicRadiosity, LightShape
from hr_addon.core.gather import LoopGather, hostvis
from hr_addon.core.radiosity import RadiositySystem
from hr_addon.core.refine import RefineParams
from hr_addon.io import precompute as pc

DRAFT = RefineParams.preset("draft")
GATHER = dict(rays=16, shadow_rays=4, levels=2, iterations=2)
MESH = scenes.cornell_box()
WANT = pc.expected(MESH, DRAFT, gather=GATHER)


def shape(cx):
    rect = S.on_plane(S.rect(0.2, 0.15, centre=(cx, 0.3)), S.CORNELL_BACK_WALL)
    return LightShape(rect, np.full(3, 5.0), "r")


def build():
    system = RadiositySystem(MESH, DRAFT)
    return system, LoopGather(DynamicRadiosity(system, method="FE"), **GATHER)


def stores(gather):
    return [H for lv in hostvis.host_levels(gather) for H in getattr(lv, "_host_stores", {}).values()]


def rays(gather):
    return sum(H.rays + H.event_rays for H in stores(gather))


def bake(d, log=None):
    """(gather, outputs, rays traced): the folder's precompute loaded (with its kept segments) and
    three frames of the shape moving, as a bake's events."""
    log = [] if log is None else log
    system, gather, how = pc.load_or_build(d, WANT, build, log=log.append)
    dyn = DynamicRadiosity(system.copy(), method="FE")
    out = []
    for cx in (0.25, 0.3, 0.36):
        dyn.apply({"s": shape(cx)})
        out.append(np.array(gather.loop_radiance(dyn)))
    return gather, out, rays(gather)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A cache folder with a precompute (no segments kept) and a bake's outputs from it."""
    d = tmp_path_factory.mktemp("hk") / "cache"
    system, gather = build()
    pc.write(d, *pc.capture(system, gather), WANT)
    g, out, n = bake(d)
    assert n > 0 and not (d / pc.KEPTNAME).exists()
    return d, out, g


def copy_folder(src, dst):
    shutil.copytree(src, dst)
    return dst


def assert_same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_a_bake_from_kept_segments_equals_a_fresh_bake_bit_for_bit(folder, tmp_path):
    """The second bake loads what the first traced: the same values, no ray for segments traced
    before; the file is written only when a bake traced new ones."""
    d0, fresh, _ = folder
    d = copy_folder(d0, tmp_path / "c")
    g, out, n = bake(d)
    log = []
    assert pc.keep(d, g, log=log.append) == d / pc.KEPTNAME and "segments stored" in log[0], log
    log = []
    g2, again, n2 = bake(d, log)
    assert any("host visibility segments loaded" in line for line in log), log
    assert n2 == 0 < n
    assert_same(again, fresh)
    assert_same(out, fresh)
    before = (d / pc.KEPTNAME).read_bytes()
    assert pc.keep(d, g2) is None and (d / pc.KEPTNAME).read_bytes() == before  # nothing new
    # a bake that reads more (a new place) traces only that and keeps the union
    system, g3, _ = pc.load(d, WANT)
    dyn = DynamicRadiosity(system.copy(), method="FE")
    dyn.apply({"s": shape(0.45)})
    v = np.array(g3.loop_radiance(dyn))
    assert 0 < rays(g3) and pc.keep(d, g3)
    g4 = pc.load(d, WANT)[1]
    assert len([t for H in stores(g4) for t in (*H.tiles, *H.part)]) > len(
        [t for H in stores(g2) for t in (*H.tiles, *H.part)]
    )
    np.testing.assert_array_equal(np.array(g4.loop_radiance(dyn)), v)
    assert rays(g4) == 0


def test_the_file_round_trips_every_tile_and_its_read_order(folder):
    _, _, g = folder
    arrays, info = hostvis.kept(g)
    assert info["tiles"] > 0 and info["left_out"] == 0
    g2 = pc.load(folder[0], WANT)[1]  # (no segments kept there)
    assert hostvis.restore_kept(g2, arrays) == info["tiles"]
    for A, B in zip(hostvis.host_levels(g), hostvis.host_levels(g2)):
        sa, sb = getattr(A, "_host_stores", {}), getattr(B, "_host_stores", {})
        assert sa.keys() == sb.keys()
        for k, H in sa.items():
            K = sb[k]
            assert H.tiles.keys() == K.tiles.keys() and H.part.keys() == K.part.keys()
            for t in H.part:
                for x, y in zip(H.part[t], K.part[t]):
                    np.testing.assert_array_equal(x, y)
            assert (H.n.tobytes(), H.o.tobytes()) == (K.n.tobytes(), K.o.tobytes())
            order = lambda S: sorted(S.used, key=S.used.get)  # noqa: E731
            assert order(H) == order(K)
    # the disk cap keeps the tiles read last
    small, sinfo = hostvis.kept(g, cap=info["bytes"] // 3)
    assert 0 < sinfo["tiles"] < info["tiles"] and sinfo["left_out"] == info["tiles"] - sinfo["tiles"]
    newest = sorted(
        (
            (H.used[t], li, t)
            for li, lv in enumerate(hostvis.host_levels(g))
            for H in getattr(lv, "_host_stores", {}).values()
            for t in (*H.tiles, *H.part)
        ),
        reverse=True,
    )[: sinfo["tiles"]]
    got = {
        (int(li), tuple(t))
        for li, t in zip(
            small["store_info"][small["tile_info"][:, 0], 0], small["tile_info"][:, 1:4].tolist()
        )
    }
    assert got == {(li, t) for _, li, t in newest}


def test_a_stale_file_is_ignored_and_said(folder, tmp_path):
    """Segments traced on another precompute file (the scene or settings changed, Rebuild) or under
    other host visibility settings are never used: said, and the values are a fresh bake's."""
    d0, fresh, _ = folder
    d = copy_folder(d0, tmp_path / "c")
    g, _, _ = bake(d)
    pc.keep(d, g)
    kept = (d / pc.KEPTNAME).read_bytes()
    # a new precompute written into the folder (rebuilt: another scene, settings, Rebuild; here
    # the same scene, which a digest of the key alone would take for the old one)
    pc.write(d, *pc.capture(*pc.load(d0, WANT)[:2]), WANT)
    assert (d / pc.KEPTNAME).read_bytes() == kept  # (left: a cancel after the build keeps it)
    log = []
    g2, out, n = bake(d, log)
    assert any("not used: traced on another precompute" in line for line in log), log
    assert n > 0 and not any("segments loaded" in line for line in log)
    assert_same(out, fresh)
    assert pc.keep(d, g2) and (d / pc.KEPTNAME).read_bytes() != kept  # replaced by the next bake's
    log = []
    assert n > 0 == bake(d, log)[2] and any("segments loaded" in line for line in log)
    # other host visibility settings
    d = copy_folder(d0, tmp_path / "c2")
    g, _, _ = bake(d)
    pc.keep(d, g)
    for name, value, text in (("TILE", 8, "tile 4 -> 8"), ("POINTS", 64, "points 32 -> 64")):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(hostvis, name, value)
            log = []
            _, gather, _ = pc.load_or_build(d, WANT, build, log=log.append)
        assert any(f"not used: {text}" in line for line in log), log
        assert not stores(gather)


@pytest.mark.parametrize("damage", ["truncate", "flip", "header", "foreign"])
def test_a_damaged_file_is_ignored_with_a_message(folder, tmp_path, damage):
    d0, fresh, _ = folder
    d = copy_folder(d0, tmp_path / "c")
    g, _, _ = bake(d)
    pc.keep(d, g)
    f = d / pc.KEPTNAME
    data = bytearray(f.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":  # one byte inside the largest array, the zip intact
        with zipfile.ZipFile(f) as z:
            big = max(z.infolist(), key=lambda i: i.file_size)
        data[big.header_offset + 30 + len(big.filename) + big.compress_size // 2] ^= 0xFF
    elif damage == "header":
        with zipfile.ZipFile(f) as z:
            h = z.getinfo("header.json")
        data[h.header_offset + 30 + len(h.filename)] = ord("#")
    else:  # a precompute file under the segments' name
        data = (d / pc.FILENAME).read_bytes()
    f.write_bytes(bytes(data))
    log = []
    g2, out, n = bake(d, log)
    said = [line for line in log if "segments not used" in line]
    assert said and pc.KEPTNAME in said[0], log
    assert n > 0
    assert_same(out, fresh)
    assert f.read_bytes() == bytes(data)  # (left for the next bake that traces to replace)


def test_a_failed_write_keeps_the_previous_file_and_a_bake_deletes_nothing_else(
    folder, tmp_path, monkeypatch
):
    """The write is atomic: a write that fails (disk full, a cancel inside it) leaves the previous
    file and no temporary; a file of that name that is not ours (a link, a folder) is left alone."""
    d0, _, _ = folder
    d = copy_folder(d0, tmp_path / "c")
    g, _, _ = bake(d)
    pc.keep(d, g)
    before = (d / pc.KEPTNAME).read_bytes()
    system, g2, _ = pc.load(d, WANT)
    dyn = DynamicRadiosity(system.copy(), method="FE")
    dyn.apply({"s": shape(0.45)})
    g2.loop_radiance(dyn)
    assert rays(g2) > 0
    calls = []

    def full(*a, **k):
        calls.append(1)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np.lib.format, "write_array", full)
    warned = []
    assert pc.keep(d, g2, log=lambda m: None, warn=warned.append) is None
    monkeypatch.undo()
    assert calls and "No space left" in warned[0]
    assert (d / pc.KEPTNAME).read_bytes() == before
    assert sorted(p.name for p in d.iterdir()) == sorted([".hr_radiosity", pc.FILENAME, pc.KEPTNAME])
    # not ours: a link of that name, a folder of that name
    other = tmp_path / "users_file"
    other.write_bytes(b"mine")
    (d / pc.KEPTNAME).unlink()
    (d / pc.KEPTNAME).symlink_to(other)
    warned = []
    assert pc.keep(d, g2, log=lambda m: None, warn=warned.append) is None
    assert "left alone" in warned[0] and other.read_bytes() == b"mine"
    # the precompute replaced meanwhile (another process rebuilt it): not written beside it
    (d / pc.KEPTNAME).unlink()
    pc.write(d, *pc.capture(*pc.load(d0, WANT)[:2]), WANT)
    warned = []
    assert pc.keep(d, g2, log=lambda m: None, warn=warned.append) is None
    assert "replaced meanwhile" in warned[0] and not (d / pc.KEPTNAME).exists()
    # remove() (Delete Bake, Rebuild) takes the segments with the precompute
    g3, _, _ = bake(d)
    pc.keep(d, g3)
    assert pc.remove(d) and not (d / pc.KEPTNAME).exists()


def test_a_trim_keeps_the_values_bit_for_bit(folder, monkeypatch):
    """Stores over their cap drop the tiles read longest ago; the values are the same as with no
    cap, and the stores stay within the cap (and the tile being made)."""
    d0, fresh, g = folder
    full = max(
        sum(H.nbytes for H in getattr(lv, "_host_stores", {}).values()) for lv in hostvis.host_levels(g)
    )
    cap = full // 4
    monkeypatch.setattr(hostvis, "MEMORY", cap)
    monkeypatch.setattr(hostvis, "TRIM_FLOOR", 0)  # (the floor would keep every tile of this scene)
    system, gather = pc.load(d0, WANT)[:2]
    dyn = DynamicRadiosity(system.copy(), method="FE")
    out = []
    for cx in (0.25, 0.3, 0.36):
        dyn.apply({"s": shape(cx)})
        out.append(np.array(gather.loop_radiance(dyn)))
        for lv in hostvis.host_levels(gather):
            Hs = getattr(lv, "_host_stores", {}).values()
            largest = max((hostvis._tile_bytes(H, t) for H in Hs for t in (*H.tiles, *H.part)), default=0)
            assert sum(H.nbytes for H in Hs) <= cap + largest
    assert_same(out, fresh)
    assert rays(gather) > rays(g)  # (dropped tiles traced again)
    # the floor: a level keeps at least TRIM_FLOOR tiles of all its samples, whatever MEMORY says
    # (a cap below one event's reads would make every step trace again what the last one read)
    monkeypatch.setattr(hostvis, "TRIM_FLOOR", 16)
    for lv in hostvis.host_levels(g):
        held = sum(H.nbytes for H in getattr(lv, "_host_stores", {}).values())
        assert held < 16 * 9 * lv.n and hostvis.trim(lv, cap=1) == 0
