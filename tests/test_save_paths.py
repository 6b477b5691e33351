"""Save paths from requests: plain names inside the maps directory, everything else refused before any write."""

from __future__ import annotations

from pathlib import Path

import pytest

from fleetslam.errors import UnsafePathError
from fleetslam.save_paths import save_path


def test_a_plain_name_lands_in_the_directory_which_is_created(tmp_path: Path) -> None:
    path = save_path(tmp_path / "maps", "c3po-2026_11.bt", suffixes=(".bt",))
    assert path == tmp_path / "maps" / "c3po-2026_11.bt" and path.parent.is_dir()


@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("/etc/passwd.bt", "not a plain file name"),
        ("../map.bt", "not a plain file name"),
        ("..", "not a plain file name"),
        ("a/../../map.bt", "not a plain file name"),
        ("sub/map.bt", "not a plain file name"),
        ("sub\\map.bt", "not a plain file name"),
        (".bashrc.bt", "not a plain file name"),
        ("map\x00.bt", "not a plain file name"),
        ("", "not a plain file name"),
        ("m" * 200 + ".bt", "not a plain file name"),
        ("map.db", "must end in .bt"),
        ("map", "must end in .bt"),
    ],
)
def test_names_that_leave_the_directory_or_are_not_maps_are_refused(tmp_path: Path, name: str, reason: str) -> None:
    with pytest.raises(UnsafePathError, match=reason):
        save_path(tmp_path / "maps", name, suffixes=(".bt",))
    assert not (tmp_path / "maps").exists()  # refused before anything was created


def test_a_link_inside_the_directory_is_not_written_through(tmp_path: Path) -> None:
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "map.bt").symlink_to(tmp_path / "secret.bt")
    with pytest.raises(UnsafePathError, match="is a link"):
        save_path(tmp_path / "maps", "map.bt", suffixes=(".bt",))
