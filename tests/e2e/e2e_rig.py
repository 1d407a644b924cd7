"""A station with the listeners the e2e tests read back: alarms, the frames kept, the view."""
from __future__ import annotations

from ropemon.lab.demo import FrameKeeper
from ropemon.station.monitor import MonitorView
from ropemon.station.pipeline import Acknowledge, AlarmListener, HoistPipeline


class Rig(HoistPipeline):
    def __init__(self, keys, settings=None, site=None, clock=None, store=None):
        from ropemon.station.pipeline import StoreListener
        self.alarm_listener = AlarmListener(settings)
        self.kept = FrameKeeper()
        self.view = MonitorView(site)
        listeners = [self.alarm_listener] + ([StoreListener(store)] if store is not None else [])
        super().__init__(keys, listeners + [self.kept, self.view], clock=clock, resume_from=store)

    @property
    def frames(self):
        return self.kept.frames

    @property
    def alarms(self):
        return self.alarm_listener.engine

    @property
    def new_raises(self):
        return self.view.new_raises

    def ack_all(self, operator: str = "tester") -> None:
        self.submit(Acknowledge(operator, "test"))
        self.pump()
