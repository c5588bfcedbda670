"""Scene, camera and export I/O. See ``README.md`` in this folder."""
