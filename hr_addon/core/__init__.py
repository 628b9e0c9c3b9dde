"""Dynamic hierarchical radiosity core: numpy only, no bpy (tests/test_core_isolation.py enforces it).
A map of the modules: docs/ARCHITECTURE.md."""
