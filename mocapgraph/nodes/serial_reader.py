"""Serial marker device node (pyserial): the text or binary wire protocol from a serial port.

The protocols are specified in :mod:`mocapgraph.formats.wire_protocol` (text: one frame per
line, ``F <frame> <t_us> <n> x y z ... [*crc]``, millimetres; binary: 24 + 12 n byte frames with
magic, counter, time stamp and CRC-32). A port that cannot be opened or that vanishes (USB cable
pulled) is retried with doubling back-off; the node stays alive, counts it and says so in
``reader_status``. Garbage on the line is skipped and counted.
"""
from __future__ import annotations

import errno
import os
import time
from typing import Any

import serial

from ..bus import Param
from .device_stream import WireDeviceSource

READ_CHUNK = 65536


class SerialReader(WireDeviceSource):
    """Reads a marker device on a serial port (``port``, ``baud``, ``protocol``) and publishes
    ``markers`` + latched ``marker_layout``. Positions are millimetres on the wire, metres in the
    world frame after the device file's transform; capture stamps are the device's time stamps
    mapped to our clock on the first frame. Lost or absent ports are reopened with back-off
    (``reopen_s`` doubling up to ``reopen_max_s``); bad bytes are counted and logged, rate-limited.
    """

    summary = "marker device on a serial port (text or binary wire protocol, reconnects with back-off)"
    port = Param("/dev/ttyUSB0", "serial port path, e.g. /dev/ttyUSB0, /dev/serial/by-id/..., /dev/pts/3")
    baud = Param(115200, "baud rate (ignored by USB CDC and pseudo-terminals)", minimum=50)
    protocol = Param("text", "wire protocol: 'text' (one frame per line) or 'binary'", choices=("text", "binary"))
    reopen_s = Param(0.2, "first wait before reopening a lost or absent port, s (doubles each failure)",
                     minimum=0.01)
    reopen_max_s = Param(5.0, "longest wait between reopen attempts, s", minimum=0.01)

    def wire_protocol(self) -> str:
        return self.protocol

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.endpoint = self.port
        self.ser: serial.Serial | None = None
        self.reopen_attempts = 0
        self._backoff = self.reopen_s
        self._reopen_timer: list | None = None

    def on_start(self) -> None:
        if not self.start_layout():
            return
        self._try_open(first=True)

    # ----- the port ---------------------------------------------------------------------------
    def _try_open(self, first: bool = False) -> None:
        try:
            ser = serial.Serial(self.port, self.baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as exc:
            self.reopen_attempts += 1
            why = os.strerror(exc.errno) if getattr(exc, "errno", None) else str(exc)
            if getattr(exc, "errno", None) == errno.EACCES:
                why += " (on Linux, add your user to the 'dialout' group)"
            self.warn_limited("open", "cannot open %s (%s); retrying every %.1f s at most",
                              self.port, why, self.reopen_max_s, every_s=10.0)
            self.set_state("reconnecting" if self.disconnects else "waiting",
                           f"cannot open {self.port}: {why}")
            self._schedule_reopen()
            return
        self.ser = ser
        self._backoff = self.reopen_s
        if self._reopen_timer is not None:
            self._reopen_timer.cancel()
            self._reopen_timer = None
        self.watch_fd(ser.fileno())
        self.log.info("%s %s at %d baud (%s protocol)", "opened" if not self.disconnects else "reopened",
                      self.port, self.baud, self.protocol)
        self.set_state("streaming", f"{self.port}, {self.protocol} protocol")

    def _schedule_reopen(self) -> None:
        if self._reopen_timer is not None:
            self._reopen_timer.cancel()
        self._reopen_timer = self.add_timer(self._backoff, self._try_open)
        self._backoff = min(self._backoff * 2, self.reopen_max_s)

    def _lost(self, why: str) -> None:
        self.disconnects += 1
        self.unwatch_fd()
        try:
            self.ser.close()
        except (serial.SerialException, OSError):
            pass
        self.ser = None
        self.reset_stream()
        self.log.warning("lost %s (%s); reopening with back-off (disconnect %d)", self.port, why, self.disconnects)
        self.set_state("reconnecting", f"{self.port} lost: {why}")
        self._schedule_reopen()

    def read_device(self) -> None:
        if self.ser is None:
            return
        try:
            data = self.ser.read(READ_CHUNK)
        except (serial.SerialException, OSError) as exc:
            self._lost(str(exc))
            return
        if data:
            self.handle_bytes(data, time.time_ns())

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["reopen_attempts"] = self.reopen_attempts
        return d

    def on_stop(self) -> None:
        super().on_stop()
        if self.ser is not None:
            self.ser.close()
