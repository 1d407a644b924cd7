"""`MICROPYPATH=firmware micropython -m ropenode.sim_main [--boot-file F] CONFIG RSENS OUT`: see hal_sim."""
import sys

from ropenode.hal_sim import run_sim

USAGE = "usage: micropython -m ropenode.sim_main [--boot-file F] CONFIG RSENS OUT"


def main(argv):
    boot_file = None
    if "--boot-file" in argv:
        i = argv.index("--boot-file")
        if i + 1 >= len(argv) - 3:
            print(USAGE, file=sys.stderr)
            return 2
        boot_file = argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    if len(argv) < 3:
        print(USAGE, file=sys.stderr)
        return 2
    try:
        samples, frames = run_sim(argv[-3], argv[-2], argv[-1], boot_file)
    except (OSError, ValueError) as e:
        print("ropenode.sim_main: %s" % (e,), file=sys.stderr)
        return 1
    print("samples %d frames %d" % (samples, frames))
    return 0


sys.exit(main(sys.argv[1:]))
