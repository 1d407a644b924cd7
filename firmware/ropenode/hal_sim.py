"""Simulation HAL for the unix port: .rsens samples in from a stream, radio bytes out.

    MICROPYPATH=firmware micropython -m ropenode.sim_main [--boot-file F] CONFIG RSENS OUT

or from Python (CPython with the ropemon shim, or MicroPython):

    from ropenode.hal_sim import run_sim
    samples, frames = run_sim("firmware/node.json", "in.rsens", "out.bin", boot_file=None)

Frame seq numbers (ropenode.bootseq): without a boot file the boot counter is
0, so the same input always gives the same bytes (`ropemon replay`); with one,
each run is a new boot, as a reset is on the cage, and seq keeps increasing.

OUT receives exactly the bytes the node would hand to its radio: COBS frames,
each ended by 0x00 (docs/protocol.md). A missing or invalid CONFIG does not
stop the run: the node sends config-fault status frames, as on the cage
(signed with the file's node_id and key when those are still valid,
config.load_for_boot), and the reason goes to stderr.
"""
import array
import struct
import sys

from ropenode import config as _config
from ropenode import layout
from ropenode import rsens
from ropenode.bootseq import FrameSeq
from ropenode.node import Node


class SimHal:
    """Reads records of one .rsens stream into a preallocated array('H')."""

    def __init__(self, stream):
        head = stream.read(rsens.HEADER_LEN)
        if head is None or len(head) < rsens.HEADER_LEN:
            raise ValueError("sensor stream: too short for a .rsens header")
        magic, version, ropes, hz, _ = struct.unpack(rsens.HEADER, head)
        if magic != rsens.MAGIC or version != 1:
            raise ValueError("sensor stream: not a version-1 .rsens stream")
        if not 1 <= ropes <= 4 or hz == 0:
            raise ValueError("sensor stream: %d ropes at %d Hz is not valid" % (ropes, hz))
        self.stream = stream
        self.ropes = ropes
        self.sample_hz = hz
        self.rec = array.array("H", bytes(2 * (2 * ropes + 4)))
        self.rec_bytes = 2 * len(self.rec)

    def read(self):
        """Fill self.rec with the next record; False at the end of the stream."""
        n = self.stream.readinto(self.rec)
        return n == self.rec_bytes


def run_sim(config_path, rsens_path, out_path, boot_file=None):
    """Run the node over a whole .rsens file; return (samples, frames written).

    `boot_file`: the persisted boot counter (incremented by this run), or None for boot 0."""
    cfg, node_id, key, reason = _config.load_for_boot(config_path)
    if reason:
        print("ropenode: %s - sending config-fault status frames as node %d, %s"
              % (reason, node_id, "signed with its key" if key else "unsigned"), file=sys.stderr)
    with open(rsens_path, "rb") as src:
        hal = SimHal(src)
        if cfg is not None and (cfg.ropes != hal.ropes or cfg.sample_hz != hal.sample_hz):
            raise ValueError("sensor stream has %d ropes at %d Hz, config says %d at %d"
                             % (hal.ropes, hal.sample_hz, cfg.ropes, cfg.sample_hz))
        node = Node(cfg, node_id, key, seq=FrameSeq(boot_file))
        wire = bytearray(layout.MAX_WIRE_LEN)
        wmv = memoryview(wire)
        samples = frames = 0
        rec = hal.rec
        with open(out_path, "wb") as out:
            while hal.read():
                samples += 1
                if node.sample(rec):
                    n = node.frame_into(wire)
                    out.write(wmv[:n])
                    frames += 1
    return samples, frames
