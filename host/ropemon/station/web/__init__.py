"""The web face of the station: live pages, trends, alarms, trips, over HTTP (docs/web.md).

Its libraries (Starlette, uvicorn, Jinja2, argon2-cffi, itsdangerous, python-multipart) are the
`web` extra; nothing else of the station imports this package (faces.py names it by string).
"""
