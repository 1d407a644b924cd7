"""pytest setup shared by every test: node modules importable under CPython, and
hypothesis drawing the same examples on every run (`make test` and CI give the same
verdict twice); ROPEMON_HYPOTHESIS=explore draws new ones each run, to search further.
SIGINT handled here even where the suite was started with it ignored (a shell's background
job): the commands the tests start and stop with Ctrl-C would inherit the ignore and never stop."""
import os
import signal

from hypothesis import settings

from ropemon.firmware import install_shim

install_shim()

if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("ROPEMON_HYPOTHESIS") == "explore" else "repeatable")
