"""Cage node boot: run the board loop; a bad /node.json gives status frames, never a crash loop.

An unexpected exception is printed and the loop is restarted after a pause
(the watchdog, fed only while sampling is healthy, covers a hang).
"""
import sys
import time

while True:
    try:
        from ropenode import hal_board
        hal_board.run("/node.json")
    except KeyboardInterrupt:
        raise
    except Exception as e:  # keep the node alive: report, wait, start again
        sys.print_exception(e)
        time.sleep(1)
