"""bench/fetch_emps.py: downloads checked by SHA-256, a clear refusal when it cannot."""

import hashlib
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, 'bench'))

import fetch_emps  # noqa: E402, I100


def _mirror(tmp_path, content):
    mirror = tmp_path / 'mirror'
    mirror.mkdir()
    for name in fetch_emps.FILES:
        (mirror / name).write_bytes(content)
    return mirror.as_uri() + '/'


def test_an_unreachable_source_fails_naming_the_url_and_the_way_out(tmp_path):
    with pytest.raises(SystemExit, match='could not download .*nonlinearbenchmark.org'):
        fetch_emps.fetch(str(tmp_path / 'out'), (tmp_path / 'nowhere').as_uri() + '/')


def test_a_file_that_is_not_the_published_one_is_refused(tmp_path):
    with pytest.raises(SystemExit, match='SHA-256 differs'):
        fetch_emps.fetch(str(tmp_path / 'out'), _mirror(tmp_path, b'not EMPS'))
    assert not any((tmp_path / 'out').iterdir())


def test_the_published_files_are_written(tmp_path, monkeypatch):
    content = b'stand-in for a .mat file'
    digest = hashlib.sha256(content).hexdigest()
    monkeypatch.setattr(fetch_emps, 'FILES', {name: digest for name in fetch_emps.FILES})
    paths = fetch_emps.fetch(str(tmp_path / 'out'), _mirror(tmp_path, content))
    assert [open(path, 'rb').read() for path in paths] == [content, content]
    # Present with the right checksum: kept, no download needed.
    assert fetch_emps.fetch(str(tmp_path / 'out'), (tmp_path / 'nowhere').as_uri()) == paths
