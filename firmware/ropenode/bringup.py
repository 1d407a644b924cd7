"""Bench bring-up of a board at the REPL (docs/hardware.md, "Bench bring-up"):

    mpremote connect PORT mount firmware exec "from ropenode import bringup; bringup.bench()"

Kept out of hal_board so that the running node does not hold its code.
"""
import time

from ropenode.hal_board import Board


def bench(board=None, ropes=4, temp_fitted=False, records=3):
    """Bring-up at the REPL (docs/hardware.md): the I2C scan against the table, then
    `records` records: each loop's stream word, current (uA) and NAMUR state, the
    battery (mV), encoder and Hall words, and how long one record took (it must stay
    well inside 1 / sample_hz). Not for the sample loop: it allocates."""
    from ropenode import boards

    t = boards.get(board)
    b = Board(None, ropes, 200, temp_fitted, t)
    found = b.i2c.scan()
    print("I2C: found", [hex(a) for a in found], "- table", [hex(a) for a in t["ads"]],
          "OK" if all(a in found for a in t["ads"]) else "MISSING")
    fe = b.fe
    fs, shunt = t["fs_mv"], t["shunt_ohm"]
    state = ("ok", "LOW (<3.6 mA)", "HIGH (>21 mA)")
    for _ in range(records):
        fe.k = 0  # every record reads the battery (and temperature) too
        t0 = time.ticks_us()
        fe.acquire()
        us = time.ticks_diff(time.ticks_us(), t0)
        rec = fe.rec
        for i in range(2 * ropes):
            ua = boards.loop_ua(rec[i], fs, shunt)
            print("%s %d: word %5d  %2d.%03d mA  %s" % ("pressure" if i < ropes else "displacement",
                  i % ropes + 1, rec[i], ua // 1000, ua % 1000, state[boards.loop_state(rec[i], fs, shunt)]))
        from ropenode.ads1115 import code_uv
        mv = code_uv(rec[2 * ropes] >> boards.WORD_SHIFT, fs) * t["battery_div"] // 1000
        print("battery: word %d  %d mV; temperature word %d; encoder %d; hall %d"
              % (rec[2 * ropes], mv, rec[2 * ropes + 1], rec[2 * ropes + 2], rec[2 * ropes + 3]))
        print("record: %d us (1/sample_hz: 5000 us at 200 Hz); bus errors %d, timeouts %d, rdy timeouts %d"
              % (us, fe.bus_errors, fe.timeouts, fe.rdy_timeouts))
