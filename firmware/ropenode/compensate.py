"""One sample of the rope-tension compensation for all ropes (docs/model.md):

    T_i = p_tap,i A_i + dp_i(Q_i) A_i + F_i

raw tension p_tap A (channels), loss force (loss), LuGre friction (lugre),
all in integer N. A rope is `good` when both its loops read inside their
limits and each has read a good value once; only good ropes get a tension.
Allocation-free.
"""
import array

from ropenode.channels import Channels
from ropenode.loss import Loss
from ropenode.lugre import LuGre
from ropenode.velocity import Velocity


class Compensator:
    def __init__(self, cfg):
        n = self.n = cfg.ropes
        self.all = (1 << n) - 1
        self.ch = Channels(cfg)
        self.vel = Velocity(cfg)
        self.loss = Loss(cfg)
        self.fric = LuGre(cfg)
        self.tension_n = array.array("i", [0] * n)  # compensated, N (valid where `good`)
        self.raw_tension_n = self.ch.raw_tension_n  # p_tap * A, N
        self.p_kpa = self.ch.p_kpa
        self.good = 0
        self.fault_mask = 0

    def step(self, rec, temp_cc):
        """Compensate one record; temp_cc selects the loss table rows."""
        ch = self.ch
        allb = self.all
        mask = ch.read(rec)
        self.fault_mask = mask
        dgood = ~(mask >> 4) & (ch.seen >> 4) & allb
        vel = self.vel
        vel.update(ch.x_q8um, dgood)
        loss = self.loss
        loss.set_temp(temp_cc)
        loss.update(vel.v_um_s)
        fr = self.fric
        fr.update(ch.p_kpa, vel.dx_q8um, vel.v_um_s, allb)
        raw = ch.raw_tension_n
        ln = loss.loss_n
        fn = fr.friction_n
        t = self.tension_n
        for i in range(self.n):
            t[i] = raw[i] + ln[i] + fn[i]
        self.good = ~mask & dgood & ch.seen & allb
        return self.good
