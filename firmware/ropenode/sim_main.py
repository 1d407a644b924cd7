"""`MICROPYPATH=firmware micropython -m ropenode.sim_main CONFIG RSENS OUT`: see hal_sim."""
import sys

from ropenode.hal_sim import run_sim


def main(argv):
    if len(argv) < 3:
        print("usage: micropython -m ropenode.sim_main CONFIG RSENS OUT", file=sys.stderr)
        return 2
    try:
        samples, frames = run_sim(argv[-3], argv[-2], argv[-1])
    except (OSError, ValueError) as e:
        print("ropenode.sim_main: %s" % (e,), file=sys.stderr)
        return 1
    print("samples %d frames %d" % (samples, frames))
    return 0


sys.exit(main(sys.argv[1:]))
