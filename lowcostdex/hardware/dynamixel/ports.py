"""Serial port discovery for ``lowcostdex scan`` / ``setup-motors`` without ``--port``.

``list_serial_ports`` asks pyserial (``serial.tools.list_ports.comports``) for the serial ports,
keeps the USB ones (a U2D2 is an FTDI FT232H, USB id 0403:6014), and adds what decides whether
a port will work: its ``/dev/serial/by-id`` names (stable across replugging), whether this user
may open it (and the group to join if not) and, for USB-serial adapters, the latency timer (16 ms
by default on Linux, which makes every read wait; 1 ms is what a control loop needs).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from lowcostdex.errors import InputError
from lowcostdex.hardware.dynamixel import transport

U2D2_USB_ID = (0x0403, 0x6014)  # FTDI FT232H, the ROBOTIS U2D2 (05-dynamixel-protocol.md sec. 5)
BY_ID_DIR = Path("/dev/serial/by-id")


@dataclass(frozen=True)
class SerialPortInfo:
    """One candidate serial port.

    Attributes:
      device: device path (/dev/ttyUSB0).
      vid, pid: USB vendor and product id (None: not USB).
      serial_number, description, manufacturer: as the USB device reports them.
      by_id: /dev/serial/by-id names that point to this device.
      group: group owning the device node (None: unknown).
      accessible: this process may open it for reading and writing.
      in_group: this user is a member of ``group`` in the group database (maybe not yet in this
        login session); None when unknown.
      latency_ms: USB-serial latency timer [ms] (None: not readable, e.g. not a USB-serial tty).
      latency_path: the sysfs file that holds it.
    """

    device: str
    vid: int | None
    pid: int | None
    serial_number: str | None
    description: str
    manufacturer: str | None
    by_id: tuple[str, ...]
    group: str | None
    accessible: bool
    in_group: bool | None
    latency_ms: int | None
    latency_path: str | None

    @property
    def usb_id(self) -> str:
        return "-" if self.vid is None else f"{self.vid:04x}:{self.pid:04x}"

    @property
    def is_u2d2(self) -> bool:
        return (self.vid, self.pid) == U2D2_USB_ID

    def problems(self) -> list[str]:
        """What stops this port from working well, each with the fix."""
        out = []
        if not self.accessible:
            group = self.group or "dialout"
            if self.in_group:
                out.append(f"no permission to open {self.device}: you are in group '{group}' "
                           "but this login session is not yet; log out and in again (or run "
                           f"`newgrp {group}`)")
            else:
                out.append(f"no permission to open {self.device} (owned by group '{group}'): "
                           f"sudo usermod -aG {group} $USER, then log out and in again")
        if self.latency_ms is not None and self.latency_ms > 1:
            out.append(f"USB latency timer is {self.latency_ms} ms (every read waits for it): "
                       f"echo 1 | sudo tee {self.latency_path}")
        return out


def list_serial_ports(*, comports: Callable[[], Iterable] | None = None,
                      by_id_dir: Path | None = None, sysfs: Path | None = None,
                      usb_only: bool = True) -> list[SerialPortInfo]:
    """The serial ports a Dynamixel adapter could be on, U2D2s first.

    Args:
      comports: pyserial's port lister (default ``serial.tools.list_ports.comports``).
      by_id_dir: where the stable by-id symlinks live (default ``BY_ID_DIR``).
      sysfs: the usb-serial sysfs folder with the latency timers (default
        ``transport.SYSFS_USB_SERIAL``).
      usb_only: leave out ports without a USB id (built-in UARTs such as /dev/ttyS0).
    """
    if comports is None:
        from serial.tools import list_ports

        comports = list_ports.comports
    by_id_dir = BY_ID_DIR if by_id_dir is None else by_id_dir
    sysfs = transport.SYSFS_USB_SERIAL if sysfs is None else sysfs
    links = _by_id_links(by_id_dir)
    out = []
    for p in comports():
        if usb_only and p.vid is None:
            continue
        real = os.path.realpath(p.device)
        group, in_group = _group_of(p.device)
        latency = transport.usb_latency_timer(p.device, sysfs)
        out.append(SerialPortInfo(
            device=p.device, vid=p.vid, pid=p.pid, serial_number=p.serial_number,
            description=p.description or "", manufacturer=p.manufacturer,
            by_id=tuple(sorted(name for name, target in links if target == real)),
            group=group, accessible=os.access(p.device, os.R_OK | os.W_OK), in_group=in_group,
            latency_ms=latency,
            latency_path=str(sysfs / Path(real).name / "latency_timer") if latency is not None
            else None))
    return sorted(out, key=lambda i: (not i.is_u2d2, i.device))


def format_ports(ports: list[SerialPortInfo]) -> str:
    """A table of the ports and, under each, its problems and fixes."""
    if not ports:
        return ("no USB serial port found: plug in the U2D2 (USB id 0403:6014); `dmesg | tail` "
                "shows whether the kernel sees it")
    lines = [f"{'port':<14} {'usb id':<9} {'serial':<12} {'latency':>7}  description / by-id"]
    for p in ports:
        lat = "-" if p.latency_ms is None else f"{p.latency_ms} ms"
        name = p.description + ("  [U2D2]" if p.is_u2d2 else "")
        lines.append(f"{p.device:<14} {p.usb_id:<9} {p.serial_number or '-':<12} {lat:>7}  "
                     f"{name}")
        lines += [f"{'':<14} by-id: {link}" for link in p.by_id]
        lines += [f"{'':<14} ! {problem}" for problem in p.problems()]
    return "\n".join(lines)


def _by_id_links(folder: Path) -> list[tuple[str, str]]:
    """(link path, resolved target) of every symlink in ``folder``."""
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return []
    return [(str(e), os.path.realpath(e)) for e in entries if e.is_symlink()]


def _group_of(device: str) -> tuple[str | None, bool | None]:
    """(group owning ``device``, whether this user is a member of it in the group database)."""
    try:
        import grp
        import pwd
    except ImportError:  # not POSIX
        return None, None
    try:
        gid = os.stat(device).st_gid
        group = grp.getgrgid(gid)
    except (OSError, KeyError):
        return None, None
    try:
        user = pwd.getpwuid(os.getuid())
    except KeyError:
        return group.gr_name, None
    return group.gr_name, user.pw_gid == gid or user.pw_name in group.gr_mem


SERIAL_PATTERNS = ("/dev/ttyUSB*", "/dev/ttyACM*", "/dev/tty.usbserial*", "/dev/tty.usbmodem*")
_CAN_NAME = re.compile(r"(v|sl)?can\d+")
"""SocketCAN interface names (``can0``, ``vcan0``, ``slcan0``): given to a D'Claw command, they
passed the check and failed after the output folder was written."""
_TTY_NAME = re.compile(r"tty(USB|ACM|S)\d+")
"""A serial device named without ``/dev/`` (opened relative to the working folder)."""


def check_port(port: str) -> None:
    """Refuse a serial device path that is not there or not usable, saying what to do.

    ``emulated`` and names that are not paths (Windows ``COM3``) pass; the bus reports those.
    A relative path that exists is checked too (``--port notes.txt`` made ``main`` and
    ``record-log`` write their output folders and ``setup-motors`` ask for the first motor
    before the port failed to open).
    """
    if port == "emulated" or os.name != "posix":
        return
    path = Path(port)
    if not port.startswith("/") and not path.exists():
        if os.path.exists(os.path.join("/sys/class/net", port)) or _CAN_NAME.fullmatch(port):
            raise InputError(f"--port {port} is a CAN channel (the Allegro hand's bus), not the "
                             "serial device of a Dynamixel bus (e.g. /dev/ttyUSB0); the "
                             "commands that drive the Allegro take it with --hand allegro")
        if os.path.exists(os.path.join("/dev", port)) or _TTY_NAME.fullmatch(port):
            raise InputError(f"--port {port}: no such file here; the serial device is "
                             f"/dev/{port}")
        return
    if not path.exists():
        import glob

        found = sorted(p for pattern in SERIAL_PATTERNS for p in glob.glob(pattern))
        seen = (f"serial devices present: {', '.join(found)}" if found
                else "no USB serial device is present")
        raise InputError(f"--port {port}: no such device ({seen}); plug in the USB adapter "
                         "(U2D2), check its power, or use --port emulated")
    if path.is_dir():
        raise InputError(f"--port {port} is a folder, not a serial device")
    if path.is_file():  # serial adapters and ptys are character devices
        raise InputError(f"--port {port}: cannot open it as a serial port: it is a regular "
                         "file, not a device (`lowcostdex scan` lists the serial ports)")
    if not os.access(path, os.R_OK | os.W_OK):
        raise InputError(f"--port {port}: permission denied; add yourself to the 'dialout' "
                         "group (sudo usermod -aG dialout $USER, then log in again)")


def pick_port(port: str | None) -> str:
    """``port``, or the one usable USB serial port; InputError listing the candidates else."""
    if port is not None:
        check_port(port)
        return port
    ports = list_serial_ports()
    usable = [p for p in ports if p.accessible]
    if len(usable) == 1:
        chosen = usable[0]
        print(f"using {chosen.device} ({chosen.usb_id} {chosen.description})")
        for problem in chosen.problems():
            print(f"  ! {problem}")
        return chosen.device
    what = "no usable USB serial port" if not usable else "several USB serial ports"
    raise InputError(f"{what}; pass --port. Ports found:\n{format_ports(ports)}")


def check_baud(baud: int, emulated: bool = False) -> None:
    """A positive bit rate; for the emulated motors one of the Dynamixel X rates they run at."""
    if baud <= 0:
        raise InputError(f"--baud {baud}: the bit rate must be positive (Dynamixel default "
                         "1000000, factory 57600)")
    if emulated:
        from lowcostdex.hardware.dynamixel.protocol import BAUD_CODES

        if baud not in BAUD_CODES.values():
            raise InputError(f"--baud {baud}: the emulated motors run at one of "
                             f"{', '.join(str(b) for b in sorted(BAUD_CODES.values()))} bit/s")
