"""FlowClipServer: `flowclip serve` on a free port for the length of a `with` block."""

from __future__ import annotations

import os
import queue
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from .client import Client
from .stream import Stream


def default_binary() -> Path:
    """The flowclip executable: $FLOWCLIP_BIN, else `flowclip` on PATH."""
    if os.environ.get("FLOWCLIP_BIN"):
        return Path(os.environ["FLOWCLIP_BIN"])
    found = shutil.which("flowclip")
    if found is None:
        raise FileNotFoundError("no flowclip executable: pass binary=, set FLOWCLIP_BIN or put flowclip on PATH")
    return Path(found)


class FlowClipServer:
    """`flowclip serve` on a free port, stopped with SIGINT on exit (`returncode` then holds its
    exit status). Without `exports` the exports go to a temporary directory."""

    def __init__(self, templates="templates", scenes="scenes", exports=None, *, token=None, max_body_mb=None,
                 history_cap_mb=None, max_sessions=None, recipes=None, extra_args=(), binary=None,
                 startup_timeout=30.0):
        self.binary = Path(binary) if binary else default_binary()
        self.token = token
        self._tmp = None if exports else tempfile.TemporaryDirectory(prefix="flowclip-exports-")
        self.exports = Path(exports or self._tmp.name)
        self.args = [str(self.binary), "serve", "--host", "127.0.0.1", "--port", "0", "--templates", str(templates),
                     "--scenes", str(scenes), "--exports", str(self.exports)]
        for flag, value in (("--token", token), ("--max-body-mb", max_body_mb),
                            ("--history-cap-mb", history_cap_mb), ("--max-sessions", max_sessions),
                            ("--recipes", recipes)):
            if value is not None:
                self.args += [flag, str(value)]
        self.args += list(extra_args)
        self.startup_timeout = startup_timeout
        self.proc, self.url, self.returncode = None, None, None
        self.output = []  # the server's stdout and stderr lines

    def __enter__(self):
        self.proc = subprocess.Popen(self.args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        lines = queue.Queue()

        def pump():
            for line in self.proc.stdout:
                self.output.append(line.rstrip("\n"))
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, daemon=True).start()
        deadline = time.monotonic() + self.startup_timeout
        while self.url is None:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                line = None
            m = re.search(r"listening on (http://\S+)", line or "")
            if m:
                self.url = m.group(1).rstrip("/")
            elif line is None:
                self.stop()
                raise RuntimeError(f"flowclip serve did not start: {' '.join(self.args)}\n" + "\n".join(self.output))
        return self

    def __exit__(self, *exc):
        self.stop()

    def stop(self, timeout=15.0):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            self.returncode = self.proc.returncode
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        return self.returncode

    def client(self, token=None):
        return Client(self.url, token=token if token is not None else self.token)

    def stream(self, sid, **kw):
        kw.setdefault("token", self.token)
        return Stream(self.url, sid, **kw)
