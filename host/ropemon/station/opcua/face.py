"""The OPC UA face's server: the asyncua server in its own thread and loop, its address space,
and the values of every hoist's frames and receivers (the alarm conditions: conditions.py).

asyncua is imported only inside the calls (the `opcua` extra).
"""
from __future__ import annotations

import asyncio
import datetime
import logging
import math
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ropemon.station.alarms import ActiveAlarm
from ropemon.station.faces import StationView
from ropemon.station.link import Received
from ropemon.station.opcua.certs import (CERT_FILE, TrustList, _certificate_check, _UserManager, certificate_uri,
                                         ensure_certificate)
from ropemon.station.opcua.conditions import _CALLER, SHELVING_METHODS, _Conditions
from ropemon.station.opcua.config import OpcuaConfig
from ropemon.station.opcua.history import _History, _utc
from ropemon.station.pipeline import AlarmState, Listener, StationStatus
from ropemon.station.protocol import DAN_TO_N, L, Frame
from ropemon.station.scadavalues import POS_ABSENT

log = logging.getLogger("ropemon.station.opcua")   # the face's one logger, as before it was a package

NAMESPACE = "urn:ropemon:opcua"
QUEUE_MAX = 50_000          # messages waiting for the server; past it frames are dropped (counted)

#: UNECE Rec. 20 codes of the units (OPC UA EUInformation, Part 8).
UNITS = {"kN": ("B47", "kilonewton"), "%": ("P1", "percent"), "m": ("MTR", "metre"), "mm": ("MMT", "millimetre"),
         "m/s": ("MTS", "metre per second"), "V": ("VLT", "volt"), "degC": ("CEL", "degree Celsius")}
UNECE_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


def unece_unit_id(code: str) -> int:
    """The UnitId of a UNECE common code (OPC UA Part 8: its characters as bytes, big-endian)."""
    out = 0
    for c in code:
        out = (out << 8) | ord(c)
    return out


# -- the listener: the station's thread -> the server's loop -------------------------


class OpcuaListener(Listener):
    """One hoist's messages to the OPC UA server's loop; never waits for it."""

    name = "opcua"

    def __init__(self, face: "OpcuaFace", hoist: str) -> None:
        self.face, self.hoist = face, hoist

    def on_frame(self, item: Received, now_s: float) -> None:
        self.face.post(self.hoist, "frame", item)

    def on_alarms(self, state: AlarmState) -> None:
        self.face.post(self.hoist, "alarms", state)

    def on_status(self, status: StationStatus) -> None:
        self.face.post(self.hoist, "status", status)

    def health(self) -> str | None:
        return self.face.health()


# -- the model of one hoist -----------------------------------------------------------


@dataclass
class _RopeVariables:
    tension: Any
    raw: Any
    deviation: Any
    dev_min: Any
    dev_max: Any
    area_m2: float | None
    position: Any = None           # piston position, mm from mid-stroke
    near_low: Any = None           # within the stroke margin of the retracted end (Boolean)
    near_high: Any = None          # ... of the extended end


@dataclass
class _Node:
    obj: Any
    ropes: list[_RopeVariables]
    sum: Any
    depth: Any
    speed: Any
    battery: Any
    oil: Any
    status: Any
    fault_mask: Any
    seq: Any
    links: dict[str, Any]          # receiver -> its share of this node's frames (%)
    hidden: Any = None             # the standing status: the imbalance the seals can hide (%)
    standing: Any = None           # ... and its line of text
    standing_last: tuple | None = None   # what was last written to those two


@dataclass
class _Hoist:
    id: str
    obj: Any
    alarms_obj: Any
    nodes: dict[int, _Node]
    receivers: dict[str, Any]      # receiver -> Connected (Boolean)
    db_path: Path | None
    alarms: dict[str, tuple] = None  # type: ignore[assignment]   # alarm id -> lifecycle key last emitted
    conditions: dict[str, Any] = None  # type: ignore[assignment]  # alarm id -> condition NodeId
    views: dict[str, ActiveAlarm] = None  # type: ignore[assignment]
    one_shot: dict[str, list] = None  # type: ignore[assignment]  # alarm id -> [user, seen present, shelved seen]



# -- the face ------------------------------------------------------------------------


class OpcuaFace(_Conditions):
    """The asyncua server in its own thread and loop, fed by one `OpcuaListener` per hoist."""

    def __init__(self, view: StationView, cfg: OpcuaConfig, users: Any = None) -> None:
        self.station, self.cfg, self.users = view, cfg, users
        self.loop = asyncio.new_event_loop()
        self.queue: asyncio.Queue | None = None
        self.dropped = 0
        self.error: str | None = None
        self.server: Any = None
        self.hoists: dict[str, _Hoist] = {}
        self.by_condition: dict[Any, tuple[str, str]] = {}   # condition NodeId -> (hoist, alarm id)
        self.by_shelving: dict[Any, tuple[str, str]] = {}    # its ShelvingState NodeId -> (hoist, alarm id)
        self.event_ids: dict[bytes, tuple[str, str]] = {}    # EventIds sent -> (hoist, alarm id)
        self.idx = 2
        self.app_uri = ""
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=self._run, name="opcua", daemon=True)
        self._stopping = False
        self.notified = 0      # values written

    # -- the station's side (any thread) --------------------------------------------------

    def post(self, hoist: str, kind: str, msg: Any) -> None:
        if self.queue is None or self.loop.is_closed():
            return
        try:
            self.loop.call_soon_threadsafe(self._put, (hoist, kind, msg))
        except RuntimeError:     # the loop closed meanwhile
            pass

    def _put(self, item: tuple) -> None:
        assert self.queue is not None
        try:
            self.queue.put_nowait(item)
        except asyncio.QueueFull:
            self.dropped += 1

    def health(self) -> str | None:
        if self.error is not None:
            return f"OPC UA server failed: {self.error}"
        if self._ready.is_set() and not self._thread.is_alive() and not self._stopping:
            return "OPC UA server stopped"
        return None

    def start(self, timeout_s: float = 60.0) -> None:
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"[opcua]: the server did not start within {timeout_s:.0f} s")
        if self.error is not None:
            self._thread.join(5)
            raise RuntimeError(f"[opcua]: {self.error}")

    def stop(self) -> None:
        self._stopping = True
        if self._stop is not None and self._thread.is_alive():
            self.loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30)

    def describe(self) -> str:
        who = "users from " + str(self.cfg.users) if self.cfg.users else "no users file"
        anon = ", anonymous allowed" if self.cfg.allow_anonymous else ""
        trust = (f"client certificates from {self.cfg.trusted_clients} only" if self.cfg.trusted_clients
                 else "any client certificate")
        return (f"OPC UA on {self.cfg.endpoint} ({', '.join(self.cfg.security)}; {who}{anon}; {trust}; "
                f"certificate {self.cfg.certificates / CERT_FILE})")

    # -- the server's thread ----------------------------------------------------------------

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self._serve())
        except BaseException as e:   # reported through health() and start()
            self.error = f"{type(e).__name__}: {e}"
            log.exception("OPC UA server failed")
        finally:
            self._ready.set()
            try:
                self.loop.run_until_complete(self.loop.shutdown_asyncgens())
            finally:
                self.loop.close()

    async def _serve(self) -> None:
        from asyncua import Server, ua

        self.queue = asyncio.Queue(QUEUE_MAX)
        self._stop = asyncio.Event()
        cert, key = await asyncio.to_thread(ensure_certificate, self.cfg.certificates, self.cfg.host_port[0])
        self.app_uri = certificate_uri(cert) or f"urn:ropemon:station:{socket.gethostname()}"
        trust = None
        if self.cfg.trusted_clients is not None:
            assert self.cfg.rejected_clients is not None
            trust = TrustList(self.cfg.trusted_clients, self.cfg.rejected_clients)
        server = Server(user_manager=_UserManager(self.users, self.cfg.allow_anonymous, trust))
        server.iserver.bind_condition_methods = True        # ConditionRefresh
        self.history = _History(self)
        server.iserver.history_manager.set_storage(self.history)
        await server.init()
        server.set_endpoint(self.cfg.endpoint)
        server.set_server_name(f"ropemon station {self.station.config.name}")
        await server.set_application_uri(self.app_uri)
        server.product_uri = "urn:ropemon"
        server.manufacturer_name = "ropemon"
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        server.set_security_policy([getattr(ua.SecurityPolicyType, p) for p in self.cfg.security])
        tokens: list[type] = [ua.UserNameIdentityToken]
        if self.cfg.allow_anonymous:
            tokens.insert(0, ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        if trust is not None:
            server.set_certificate_validator(_certificate_check(trust))
        self._track_callers(server)
        self.server = server
        self.idx = await server.register_namespace(NAMESPACE)
        await self._build(server)
        server.link_method(server.get_node(ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)),
                           self._acknowledge)
        for how, names in SHELVING_METHODS.items():
            for name in names:
                mid = ua.NodeId(getattr(ua.ObjectIds, name))
                if mid in server.iserver.aspace:      # asyncua 2.1's address space lacks some "2" forms
                    server.link_method(server.get_node(mid), self._shelving(how))
        await server.start()
        consumer = asyncio.create_task(self._consume())
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            consumer.cancel()
            await server.stop()

    @staticmethod
    def _track_callers(server: Any) -> None:
        """Each session's method calls run with its user in `_CALLER` (asyncua passes a method
        only the object and the arguments, not who calls)."""
        iserver = server.iserver
        make = iserver.create_session

        def create_session(*args: Any, **kw: Any) -> Any:
            s = make(*args, **kw)
            call = s.call

            async def call_as(params: Any) -> Any:
                token = _CALLER.set(s.user)
                try:
                    return await call(params)
                finally:
                    _CALLER.reset(token)
            s.call = call_as
            return s
        iserver.create_session = create_session

    # -- the address space --------------------------------------------------------------

    def _nid(self, text: str) -> Any:
        from asyncua import ua
        return ua.NodeId(text, self.idx)

    async def _object(self, parent: Any, sid: str, name: str, display: str | None = None,
                      typedef: Any = None, folder: bool = False) -> Any:
        from asyncua import ua
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = self._nid(sid)
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Object
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.Organizes if folder else ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.FolderType) if folder else (
            typedef or ua.NodeId(ua.ObjectIds.BaseObjectType))
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(display or name)
        attrs.Description = ua.LocalizedText(display or name)
        attrs.EventNotifier = 0
        item.NodeAttributes = attrs
        (res,) = await self.server.iserver.isession.add_nodes([item])
        res.StatusCode.check()
        return res.AddedNodeId

    async def _variable(self, parent: Any, sid: str, name: str, vtype: str, unit: str | None = None,
                        eu_range: tuple[float, float] | None = None, history: bool = False,
                        description: str = "") -> Any:
        from asyncua import ua
        vt = getattr(ua.VariantType, vtype)
        item = ua.AddNodesItem()
        nid = self._nid(sid)
        item.RequestedNewNodeId = nid
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        analog = unit is not None
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.AnalogItemType if analog else ua.ObjectIds.BaseDataVariableType)
        attrs = ua.VariableAttributes()
        attrs.DisplayName = ua.LocalizedText(name)
        attrs.Description = ua.LocalizedText(description or name)
        attrs.DataType = ua.NodeId(vt.value)
        attrs.ValueRank = ua.ValueRank.Scalar
        level = ua.AccessLevel.CurrentRead.mask | (ua.AccessLevel.HistoryRead.mask if history else 0)
        attrs.AccessLevel = attrs.UserAccessLevel = level
        attrs.Historizing = history
        item.NodeAttributes = attrs
        (res,) = await self.server.iserver.isession.add_nodes([item])
        res.StatusCode.check()
        node = self.server.get_node(nid)
        await self.server.write_attribute_value(
            nid, ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
        if analog:
            code, desc = UNITS[unit]
            eu = ua.EUInformation(NamespaceUri=UNECE_URI, UnitId=unece_unit_id(code),
                                  DisplayName=ua.LocalizedText(unit if unit != "degC" else "\u00b0C"),
                                  Description=ua.LocalizedText(desc))
            await node.add_property(self._nid(sid + ".EngineeringUnits"), ua.QualifiedName("EngineeringUnits", 0),
                                    ua.Variant(eu, ua.VariantType.ExtensionObject),
                                    datatype=ua.NodeId(ua.ObjectIds.EUInformation))
            lo, hi = eu_range if eu_range is not None else (-math.inf, math.inf)
            await node.add_property(self._nid(sid + ".EURange"), ua.QualifiedName("EURange", 0),
                                    ua.Variant(ua.Range(Low=lo, High=hi), ua.VariantType.ExtensionObject),
                                    datatype=ua.NodeId(ua.ObjectIds.Range))
        return nid

    async def _build(self, server: Any) -> None:
        from asyncua import ua
        root = await self._object(ua.NodeId(ua.ObjectIds.ObjectsFolder), "ropemon", "Ropemon",
                                  f"ropemon: {self.station.config.name}", folder=True)
        for h in self.station.hoists.values():
            ranges = _ranges(h)
            hid = h.id
            hobj = await self._object(root, hid, hid, h.name)
            alarms_obj = await self._object(hobj, f"{hid}.Alarms", "Alarms", f"{h.name}: alarm conditions",
                                            folder=True)
            receivers = {}
            rx_folder = await self._object(hobj, f"{hid}.Receivers", "Receivers", folder=True)
            rx_names = [name for name, _ in (h.config.receivers if h.config is not None else ())]
            for name in rx_names:
                robj = await self._object(rx_folder, f"{hid}.Receivers.{name}", name)
                receivers[name] = await self._variable(robj, f"{hid}.Receivers.{name}.Connected", "Connected",
                                                       "Boolean", description="the receiver's port is open")
            nodes = {}
            areas = list(h.figures.cylinder_area_m2)
            strokes = list(getattr(h.figures, "stroke_m", None) or ())
            for n in sorted(h.keys):
                base = f"{hid}.n{n}"
                nobj = await self._object(hobj, base, f"Node{n}", f"{h.name}: node {n}")
                ropes = []
                for k in range(len(areas)):
                    rb = f"{base}.r{k + 1}"
                    robj = await self._object(nobj, rb, f"Rope{k + 1}", f"{h.name}: node {n} rope {k + 1}")
                    rng = ranges[k] if k < len(ranges) else None
                    r = _RopeVariables(
                        await self._variable(robj, f"{rb}.Tension", "Tension", "Double", "kN", rng, history=True,
                                             description="compensated rope tension (window mean)"),
                        await self._variable(robj, f"{rb}.RawTension", "RawTension", "Double", "kN", rng,
                                             history=True, description="tap pressure x cylinder area, uncompensated"),
                        await self._variable(robj, f"{rb}.Deviation", "Deviation", "Double", "%", (-100.0, 100.0),
                                             description="from the mean of the ropes present"),
                        await self._variable(robj, f"{rb}.DeviationMin", "DeviationMin", "Double", "%",
                                             (-100.0, 100.0), description="low end of the deviation's band"),
                        await self._variable(robj, f"{rb}.DeviationMax", "DeviationMax", "Double", "%",
                                             (-100.0, 100.0), description="high end of the deviation's band"),
                        areas[k])
                    half = strokes[k] / 2 * 1000.0 if k < len(strokes) and strokes[k] else None
                    r.position = await self._variable(
                        robj, f"{rb}.Position", "Position", "Double", "mm", (-half, half) if half else None,
                        description="piston position from mid-stroke (window mean; > 0: pulled out by the rope); "
                                    "EURange: the end stops")
                    r.near_low = await self._variable(
                        robj, f"{rb}.NearRetractedEnd", "NearRetractedEnd", "Boolean",
                        description="the piston came within the stroke margin of its retracted end in the window")
                    r.near_high = await self._variable(
                        robj, f"{rb}.NearExtendedEnd", "NearExtendedEnd", "Boolean",
                        description="the piston came within the stroke margin of its extended end in the window")
                    ropes.append(r)
                    if h.db_path is not None:
                        self.history.series[r.tension] = (h.db_path, n, k, "Tension", None)
                        self.history.series[r.raw] = (h.db_path, n, k, "RawTension", areas[k])
                total = (0.0, ranges[0][1] * len(areas)) if ranges else None
                links = {}
                lobj = await self._object(nobj, f"{base}.LinkQuality", "LinkQuality", folder=True)
                for name in rx_names:
                    links[name] = await self._variable(lobj, f"{base}.LinkQuality.{name}", name, "Double", "%",
                                                       (0.0, 100.0), description="share of this node's frames "
                                                       "delivered by this receiver")
                nodes[n] = _Node(
                    nobj, ropes,
                    await self._variable(nobj, f"{base}.Sum", "Sum", "Double", "kN", total,
                                         description="sum of the rope tensions"),
                    await self._variable(nobj, f"{base}.Depth", "Depth", "Double", "m"),
                    await self._variable(nobj, f"{base}.Speed", "Speed", "Double", "m/s"),
                    await self._variable(nobj, f"{base}.Battery", "Battery", "Double", "V", (0.0, 65.535)),
                    await self._variable(nobj, f"{base}.OilTemperature", "OilTemperature", "Double", "degC",
                                         (-40.0, 150.0)),
                    await self._variable(nobj, f"{base}.Status", "Status", "UInt16",
                                         description="status bits (docs/protocol.md)"),
                    await self._variable(nobj, f"{base}.FaultMask", "FaultMask", "Byte",
                                         description="pressure/displacement channels failed (docs/protocol.md)"),
                    await self._variable(nobj, f"{base}.Seq", "Seq", "UInt32",
                                         description="the frame's sequence number"),
                    links,
                    await self._variable(nobj, f"{base}.HiddenImbalance", "HiddenImbalance", "Double", "%",
                                         (0.0, 100.0), description="standing status: the imbalance (of the mean "
                                         "rope tension) the seals' static friction can hide with the ropes equal"),
                    await self._variable(nobj, f"{base}.StandingStatus", "StandingStatus", "String",
                                         description="standing status: one line an operator reads"))
            self.hoists[hid] = _Hoist(hid, hobj, alarms_obj, nodes, receivers, h.db_path, {}, {}, {}, {})
        # the Server object emits the alarm conditions' events
        await server.get_node(ua.NodeId(ua.ObjectIds.Server)).set_event_notifier(
            [ua.EventNotifier.SubscribeToEvents, ua.EventNotifier.HistoryRead])
        for model in self.hoists.values():     # a hoist's own event history (no live events there)
            if model.db_path is not None:
                await server.get_node(model.obj).set_event_notifier([ua.EventNotifier.HistoryRead])

    # -- values -----------------------------------------------------------------------

    async def _consume(self) -> None:
        assert self.queue is not None
        while True:
            hoist, kind, msg = await self.queue.get()
            h = self.hoists.get(hoist)
            if h is None:
                continue
            try:
                if kind == "frame":
                    await self._frame(h, msg)
                elif kind == "alarms":
                    await self._alarms(h, msg)
                elif kind == "status":
                    await self._status(h, msg)
            except Exception:  # one bad message must not stop the face
                log.exception("OPC UA: hoist %s, %s", hoist, kind)

    async def _write(self, nid: Any, value: Any, vtype: Any, ts: datetime.datetime, bad: int | None = None) -> None:
        from asyncua import ua
        if value is None:
            dv = ua.DataValue(StatusCode=ua.StatusCode(bad or ua.StatusCodes.BadSensorFailure), SourceTimestamp=ts)
        else:
            dv = ua.DataValue(ua.Variant(value, vtype), SourceTimestamp=ts)
        await self.server.iserver.aspace.write_attribute_value(nid, ua.AttributeIds.Value, dv)
        self.notified += 1

    async def _frame(self, h: _Hoist, item: Received) -> None:
        from asyncua import ua
        f: Frame = item.frame
        n = h.nodes.get(f.node)
        if n is None:
            return
        ts = _utc(item.rx_time)
        D = ua.VariantType.Double
        present = [r.mean_dan for r in f.ropes if r.mean_dan != L.TENSION_ABSENT]
        mean = sum(present) / len(present) if present else 0.0
        for k, rope in enumerate(n.ropes):
            r = f.ropes[k] if k < len(f.ropes) else None
            t = None if r is None or r.mean_dan == L.TENSION_ABSENT else r.mean_dan * DAN_TO_N / 1000.0
            raw = (None if r is None or r.raw_kpa == L.RAW_KPA_ABSENT or rope.area_m2 is None
                   else r.raw_kpa * rope.area_m2)
            await self._write(rope.tension, t, D, ts)
            await self._write(rope.raw, raw, D, ts)
            dev = (r.mean_dan - mean) / mean * 100.0 if (t is not None and len(present) >= 2 and mean > 0) else None
            await self._write(rope.deviation, dev, D, ts, ua.StatusCodes.BadNoData if t is not None else None)
            if f.version < 3 or r is None:       # a version 2 node sends no position
                for nid in (rope.position, rope.near_low, rope.near_high):
                    await self._write(nid, None, D, ts, ua.StatusCodes.BadNoData)
                continue
            pos = getattr(r, "pos_01mm", POS_ABSENT)
            await self._write(rope.position, None if pos == POS_ABSENT else pos / 10.0, D, ts)
            mask = getattr(f, "stroke_mask", 0)
            await self._write(rope.near_low, bool(mask >> k & 1), ua.VariantType.Boolean, ts)
            await self._write(rope.near_high, bool(mask >> (4 + k) & 1), ua.VariantType.Boolean, ts)
        total = f.total_dan
        await self._write(n.sum, None if total is None else total * DAN_TO_N / 1000.0, D, ts)
        await self._write(n.depth, f.depth_mm / 1000.0, D, ts)
        await self._write(n.speed, f.speed_mm_s / 1000.0, D, ts)
        await self._write(n.battery, f.battery_mv / 1000.0, D, ts)
        oil = f.oil_temp_c
        await self._write(n.oil, oil, D, ts, ua.StatusCodes.BadNoData)
        await self._write(n.status, f.status, ua.VariantType.UInt16, ts)
        await self._write(n.fault_mask, f.fault_mask, ua.VariantType.Byte, ts)
        await self._write(n.seq, f.seq, ua.VariantType.UInt32, ts)

    async def _status(self, h: _Hoist, status: StationStatus) -> None:
        from asyncua import ua
        ts = _utc(time.time())
        for name, nid in h.receivers.items():
            r = status.receivers.get(name)
            if r is not None:
                await self._write(nid, bool(r.connected), ua.VariantType.Boolean, ts)
        for node, st in status.merge.items():
            n = h.nodes.get(node)
            if n is None:
                continue
            for name, nid in n.links.items():
                share = st.get("receivers", {}).get(name)
                if share is not None and share.get("share") is not None:
                    await self._write(nid, float(share["share"]) * 100.0, ua.VariantType.Double, ts)


def _ranges(h: Any) -> list[tuple[float, float]]:
    """Per rope: 0 to the pressure transmitter's full scale times the cylinder area, in kN (from
    the hoist's first node.json); else 0 to twice the rated rope tension; else none."""
    from ropemon.station.physical import load_node_json
    areas = list(h.figures.cylinder_area_m2)
    try:
        p = load_node_json(h.config.configs[0])[0]
        return [(0.0, round(p.sensor_p_max_Pa * a / 1000.0, 1)) for a in areas]
    except (ValueError, OSError, IndexError, AttributeError):
        pass
    if h.figures.rated_rope_tension_n:
        return [(0.0, 2.0 * h.figures.rated_rope_tension_n / 1000.0)] * len(areas)
    return []
