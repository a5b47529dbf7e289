import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def small_disk(tmp_path, monkeypatch):
    """A directory on a 256 KiB filesystem (tmpfs, mounted by the test where that is allowed), or, where
    it is not, one where every write past the first 200 messages fails with ENOSPC."""
    import errno
    import subprocess

    mount = tmp_path / "small_disk"
    mount.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mount)],
                             capture_output=True).returncode == 0
    if not mounted:
        from mcap.writer import Writer
        original, calls = Writer.add_message, [0]

        def add_message(self, *args, **kwargs):
            calls[0] += 1
            if calls[0] > 200:
                raise OSError(errno.ENOSPC, "No space left on device")
            return original(self, *args, **kwargs)
        monkeypatch.setattr(Writer, "add_message", add_message)
    yield mount
    if mounted:
        subprocess.run(["umount", str(mount)], check=True)
