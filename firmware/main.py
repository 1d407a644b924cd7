"""Cage node boot: finish an interrupted deploy swap, then run the board loop.

The swap is completed (deployswap.finish) before ropenode is imported, so a
power cut during `ropemon deploy` never boots a mix of old and new files. A
bad /node.json gives status frames, never a crash loop: an unexpected
exception is printed and the loop is restarted after a pause (the watchdog,
fed only while sampling is healthy, covers a hang). Ctrl-C (at the REPL, or
mpremote) stops it: the board HAL opens its maintenance window (the watchdog
re-armed with the board's long timeout, hal_board.maintenance), here too if the
Ctrl-C lands outside the loop, and the REPL is reached.
"""
import sys
import time


def _finish_deploy_swap():
    import deployswap  # swapped in before main.py (names in sorted order), and a file is never missing

    done = deployswap.finish()
    if done:
        print("deployswap: an interrupted deploy swap was rolled", done)


def _maintenance():
    try:
        from ropenode import hal_board
        hal_board.maintenance()  # nothing when no watchdog runs or the loop opened the window already
    except Exception as e:
        sys.print_exception(e)


try:
    _finish_deploy_swap()
except Exception as e:  # never keep the node from sampling: the next deploy finishes it too
    sys.print_exception(e)

try:
    while True:
        try:
            from ropenode import hal_board
            hal_board.run("/node.json")
        except Exception as e:  # keep the node alive: report, wait, start again
            sys.print_exception(e)
            time.sleep(1)
except KeyboardInterrupt:  # e.g. in the pause above, while the watchdog runs
    _maintenance()
    raise
