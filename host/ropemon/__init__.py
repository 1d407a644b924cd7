"""ropemon: host tools of the open rope tension monitor (CPython)."""
__version__ = "0.2.0"
