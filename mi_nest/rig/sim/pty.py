"""Serve a simulated device on a real pseudo-terminal, so drivers can be tested through a kernel tty.

``with PtyBridge(device) as path: serial.Serial(path, ...)``: a thread moves
bytes between the pty's master end and the device, and advances the
simulated clock with the wall clock (times ``speedup``) so motions finish.
"""
from __future__ import annotations

import os
import select
import threading
import time
import tty

from . import CLOCK


class PtyBridge:
    def __init__(self, device, speedup=1.0):
        self.device = device
        self.speedup = float(speedup)
        self._stop = threading.Event()
        self._thread = None

    def __enter__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()
        return self.path

    def _serve(self):
        last = time.monotonic()
        while not self._stop.is_set():
            readable, _, _ = select.select([self.master], [], [], 0.002)
            now = time.monotonic()
            CLOCK.sleep((now - last) * self.speedup)
            last = now
            if readable:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    return
                if not self.device.disconnected:
                    self.device.receive(data)
            self.device.poll()
            if self.device.output and not self.device.disconnected:
                written = os.write(self.master, bytes(self.device.output))
                del self.device.output[:written]

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(timeout=2)
        os.close(self.master)
        os.close(self.slave)
