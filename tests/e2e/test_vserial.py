"""Virtual serial ports: pty pairs read with pyserial carry every byte value unchanged."""
import time

import serial

from ropemon.lab.vserial import Player, VirtualPort


def test_every_byte_value_arrives_unchanged_through_pyserial():
    data = bytes(range(256)) * 8          # includes 0x00, CR, LF, XON/XOFF, ^C, ^D
    with VirtualPort("t") as vp:
        s = serial.serial_for_url(vp.port, baudrate=115200, timeout=2)
        try:
            vp.write(data)
            got = s.read(len(data))
        finally:
            s.close()
    assert got == data


def test_player_paces_events_and_reopen_keeps_the_line():
    with VirtualPort("t") as vp:
        s = serial.Serial(vp.port, timeout=2)
        events = [(0.1 * i, bytes([i + 1, 0])) for i in range(10)]
        t0 = time.monotonic()
        pl = Player(vp, events, speed=2.0)
        pl.start()
        got = b""
        while len(got) < 20 and time.monotonic() - t0 < 5:
            got += s.read(20 - len(got))
        pl.join(5)
        took = time.monotonic() - t0
        s.close()
        assert pl.error is None and got == b"".join(e[1] for e in events)
        assert 0.4 <= took < 5.0              # 0.9 s of events at 2x speed (upper bound: a busy machine)
        s2 = serial.Serial(vp.port, timeout=2)  # reopened like an unplugged adapter
        vp.write(b"again")
        assert s2.read(5) == b"again"
        s2.close()
