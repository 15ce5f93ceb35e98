"""Which paths are ROS bags (:mod:`excite.logs.bag_reader` reads them): a ``.bag``, ``.db3``
or ``.mcap`` file, a rosbag2 directory holding ``metadata.yaml``; and the parts of a bag that
cannot be opened as given, named with the way out."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["BAG_SUFFIXES", "bag_path_problem", "is_bag_path"]

BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def is_bag_path(path: str | os.PathLike[str]) -> bool:
    """Whether a path looks like a bag: a .bag, .db3 or .mcap file, a directory holding a
    rosbag2 metadata.yaml, or a part of a bag that :func:`bag_path_problem` explains (by name
    only; read_bag checks the content)."""
    p = Path(path)
    return (p.suffix.lower() in BAG_SUFFIXES or (p / "metadata.yaml").is_file()
            or bag_path_problem(p) is not None)


def bag_path_problem(path: str | os.PathLike[str]) -> str | None:
    """What is wrong with a path that is part of a ROS bag but not one excite can open (one
    line with the way out), or None: an unfinished ROS 1 recording (``.bag.active``), a
    rosbag2 directory without ``metadata.yaml`` (a recording stopped without closing it), the
    ``metadata.yaml`` or a compressed file (``.zstd``) of a rosbag2 bag given instead of its
    directory."""
    p = Path(path)
    try:
        return _bag_part(p)
    except OSError:  # an unreadable directory: opening it says what is wrong
        return None


def _bag_part(p: Path) -> str | None:
    if p.name.endswith(".bag.active"):
        return (f"{p}: an unfinished ROS 1 recording (.bag.active); `rosbag reindex {p}` "
                "repairs it, then rename it to .bag")
    if p.is_dir() and not (p / "metadata.yaml").exists() and any(
            q.name.endswith(suffix) for q in p.iterdir()
            for suffix in (".db3", ".mcap", ".db3.zstd", ".mcap.zstd")):
        return (f"{p}: a rosbag2 directory without metadata.yaml (a recording stopped without "
                f"closing it?); `ros2 bag reindex {p}` writes it")
    if p.name == "metadata.yaml":
        return f"{p}: the metadata of a rosbag2 bag; give the bag's directory {p.parent}"
    if p.suffix == ".zstd" and Path(p.stem).suffix in (".db3", ".mcap"):
        return f"{p}: a compressed file of a rosbag2 bag; give the bag's directory {p.parent}"
    return None
