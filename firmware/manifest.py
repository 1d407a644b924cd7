# Freeze the node into an ESP32 firmware image (ports/esp32: make FROZEN_MANIFEST=<this file>).
# Frozen bytecode runs from flash, so the ~35 KB of module bytecode that an
# import of .mpy files puts on the heap stays off it; /node.json stays on the
# filesystem. main.py is copied to the filesystem by `ropemon deploy`.
include("$(PORT_DIR)/boards/manifest.py")
# package() freezes every module of ropenode, the board HAL's too: hal_board (machine),
# boards (the board tables), frontend and ads1115 (the ADS1115 driver), bringup (the
# bench check at the REPL); docs/hardware.md.
package("ropenode")
