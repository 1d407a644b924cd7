"""The `ropemon` command: one subcommand per user task, each in its own module.

Each subcommand module has `add_arguments(parser)` and `run(args) -> int`; it
is imported only when its command runs, so `ropemon decode` does not pay for
matplotlib or scipy.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# command -> (module, one-line help)
COMMANDS = {
    "simulate": ("ropemon.lab.plant.cli", "run a scenario on the hoist simulator; write truth and sensor streams"),
    "replay": ("ropemon.commission.replay", "run the node firmware on a sensor stream; write the radio bytes"),
    "decode": ("ropemon.station.decode_cli", "decode frames from a capture file or stdin to JSON lines"),
    "monitor": ("ropemon.station.monitor", "live dashboard from one or more receiver serial ports"),
    "serve": ("ropemon.station.serve_cli", "run the hoists of a station file with its web and SCADA faces"),
    "user": ("ropemon.station.web.user_cli", "add, remove, list or change the password of the web face's users (argon2-hashed passwords)"),
    "fleet": ("ropemon.station.mqtt.fleet", "a fleet historian: the stations' Sparkplug B into SQL"),
    "report": ("ropemon.station.report", "per-trip summary and plots from a ropemon database"),
    "export": ("ropemon.station.store_cli", "export a ropemon database to CSV"),
    "fit-friction": ("ropemon.commission.calibrate", "fit LuGre friction parameters from test-bed data"),
    "fit-compliance": ("ropemon.commission.compliance", "fit each cylinder's hydraulic compliance from a recorded wind"),
    "config": ("ropemon.commission.config_cli", "generate a node config from a site description"),
    "deploy": ("ropemon.commission.deploy", "cross-compile and copy firmware and config to a node with mpremote"),
    "record": ("ropemon.commission.record", "arm a node to record a commissioning wind; fetch the recording"),
    "demo": ("ropemon.lab.demo", "the whole chain on the simulated hoist"),
    "evaluate": ("ropemon.lab.evaluate", "accuracy of every estimator against simulator truth"),
    "study": ("ropemon.lab.studies", "accuracy studies on evaluated runs: sensitivity, seed spread, pithead bound, ..."),
    "bench": ("ropemon.lab.bench", "benchmarks: firmware, plant, host"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `command`'s module is imported to add its arguments."""
    p = argparse.ArgumentParser(prog="ropemon", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (mod, help_) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_, description=help_)
        sp.set_defaults(_module=mod)
        if name == command:
            importlib.import_module(mod).add_arguments(sp)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((a for a in argv if not a.startswith("-")), None)
    args = build_parser(command if command in COMMANDS else None).parse_args(argv)
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
