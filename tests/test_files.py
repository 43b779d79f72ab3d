"""Atomic writes (`lerobot_skillret.files`): results land whole, with ordinary permissions."""

from __future__ import annotations

from pathlib import Path

import pytest

from lerobot_skillret.files import read_json, write_text_atomic


def test_an_atomic_write_has_the_permissions_of_a_plain_write(tmp_path: Path) -> None:
    """mkstemp creates owner-only (0600) files: results, tables and checkpoints written through it were unreadable
    to the other users of a shared machine until the mode was set like a plain write's."""
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    atomic = write_text_atomic(tmp_path / "atomic.txt", "x")
    assert atomic.read_text() == "x"
    assert atomic.stat().st_mode == plain.stat().st_mode
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_truncated_json_file_is_named(tmp_path: Path) -> None:
    path = write_text_atomic(tmp_path / "info.json", '{"total_frames": 1')
    with pytest.raises(ValueError, match=r"info\.json is not valid JSON .* truncated or corrupt"):
        read_json(path)
