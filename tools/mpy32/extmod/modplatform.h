// Stub: py/modsys.c includes this header of extmod/ (absent from the source used); nothing in it is needed.
