"""pytest setup shared by every test: node modules importable under CPython, and
hypothesis drawing the same examples on every run (`make test` and CI give the same
verdict twice); ROPEMON_HYPOTHESIS=explore draws new ones each run, to search further."""
import os

from hypothesis import settings

from ropemon.firmware import install_shim

install_shim()

settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("ROPEMON_HYPOTHESIS") == "explore" else "repeatable")
