"""A machine-wide setting (a sysfs file such as the kernel's unbound-workqueue CPU mask) shared by every drive
process of the machine: the first holder saves the value it found and writes the drive's, later holders that
ask for the same value join, and the last one out puts the saved value back. Holders are files named by
process id and start time in a directory beside a lock (flock, released by the kernel when a process dies):
a holder whose process is gone (killed with SIGKILL) is stale, dropped by the next process that takes or
gives the setting back; when it was the last, that process first puts the saved value back. No rclpy."""
import contextlib
import fcntl
import os
from pathlib import Path

HOLDERS_ROOT = "/run/pmsm_drive"
"""Where the holders of each machine-wide setting are kept (a tmpfs: emptied at boot, as the settings are)."""


def process_start(pid):
    """The start time of process ``pid`` (clock ticks since boot, /proc/PID/stat field 22), None if it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return int(stat.rsplit(")", 1)[1].split()[19])


class SharedSetting:
    """The setting in ``setting_file``, its holders in ``holders_dir`` (default: one directory per setting
    under HOLDERS_ROOT)."""

    def __init__(self, setting_file, holders_dir=None):
        self.setting_file = Path(setting_file)
        self.dir = Path(holders_dir or Path(HOLDERS_ROOT) / str(self.setting_file).strip("/").replace("/", "_"))
        self.saved = self.dir / "saved"
        self.me = self.dir / f"holder-{os.getpid()}-{process_start(os.getpid())}"

    @contextlib.contextmanager
    def _locked(self):
        self.dir.mkdir(parents=True, exist_ok=True)
        with open(self.dir / "lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            yield

    def live_holders(self):
        """{holder file: the value it holds} of the holders whose process still runs; stale ones removed."""
        live = {}
        for holder in self.dir.glob("holder-*"):
            _, pid, start = holder.name.split("-")
            if str(process_start(int(pid))) == start:
                live[holder] = holder.read_text()
            else:
                holder.unlink(missing_ok=True)
        return live

    def _restore_saved(self):
        """Put the saved value back and forget it; what was put back, or None."""
        if not self.saved.exists():
            return None
        value = self.saved.read_text()
        self.setting_file.write_text(value)
        self.saved.unlink()
        return value

    def take(self, value):
        """Hold the setting at ``value``: (None, a note or None) when held, or (why not, None) when another
        drive holds it at another value. OSError when the setting cannot be read or written."""
        with self._locked():
            live = {holder: held for holder, held in self.live_holders().items() if holder != self.me}
            note = None
            if live:
                held = set(live.values())
                if held != {value}:
                    pids = ", ".join(sorted((h.name.split("-")[1] for h in live), key=int))
                    return f"held at {held.pop()} by drive process {pids}", None
            else:
                restored = self._restore_saved()
                if restored is not None:
                    note = f"{self.setting_file} put back to {restored} (its last holder was gone)"
                found = self.setting_file.read_text().strip()
                self.setting_file.write_text(value)
                self.saved.write_text(found)
            self.me.write_text(value)
            return None, note

    def give_back(self):
        """Leave the setting; the last holder out puts the saved value back (errors ignored: best effort)."""
        with self._locked():
            self.me.unlink(missing_ok=True)
            if not self.live_holders():
                with contextlib.suppress(OSError):
                    self._restore_saved()
