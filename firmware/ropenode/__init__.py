"""ropenode: the cage node firmware of ropemon (MicroPython, also importable by CPython).

Pure logic modules never import `machine`; hardware access is behind the HAL
(`hal_board` on the reference MCU, `hal_sim` on the unix port).
"""
FIRMWARE_VERSION = "0.2.0"
