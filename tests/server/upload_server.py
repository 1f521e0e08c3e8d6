"""The app on the toy domain in a process of its own, for the crash tests of ``test_uploads.py``.

``python -m tests.server.upload_server PORT [KILL_AT]``: settings come from ``RBA_*`` env vars.
With ``KILL_AT``, the process kills itself with SIGKILL (no clean-up of any kind runs) at that
step of storing an upload:

* ``checking``: the .npz copied into its workspace, before it is checked;
* ``writing``: half-way through writing the .npz (its temporary file exists, not renamed);
* ``saved``: both files renamed into place, before the row is inserted;
* ``recorded``: the row committed, before the dataset's lock is removed.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from pathlib import Path

from rba.domains import register


def die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def install_kill(step: str) -> None:
    from rba.core.fileio import write_atomic
    from server.ops import label_admin

    check_npz, record = label_admin.check_npz, label_admin._record_upload

    def checking(path, *args):
        assert path.exists()
        die()
        return check_npz(path, *args)

    def writing(path, _arrays):
        write_atomic(path, lambda tmp: (Path(tmp).write_bytes(b"half an npz"), die()))

    def saved(*args):
        die()
        return record(*args)

    def recorded(*args):
        result = record(*args)
        die()
        return result

    patches = {"checking": ("check_npz", checking), "writing": ("save_npz", writing),
               "saved": ("_record_upload", saved), "recorded": ("_record_upload", recorded)}
    name, fn = patches[step]
    setattr(label_admin, name, fn)


def main() -> None:
    import uvicorn

    from server.common.app_settings import Settings
    from server.main import create_app

    register("toy", "tests.toy:Toy")
    if len(sys.argv) > 2:
        install_kill(sys.argv[2])
    logging.basicConfig(level=logging.WARNING)
    uvicorn.run(create_app(Settings()), host="127.0.0.1", port=int(sys.argv[1]), log_level="warning")


if __name__ == "__main__":
    main()
