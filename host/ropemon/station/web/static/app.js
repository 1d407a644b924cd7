/* ropemon web face: live pages over server-sent events, alarm actions, trends (uPlot).
 *
 * Every page that shows live data opens one EventSource: the server sends a full snapshot on
 * connect, then deltas; a reconnect gets a new snapshot, so nothing of the alarm state is lost.
 * Nothing shown is ever left looking live when it is not: a node whose last frame is older than
 * the station's stale limit greys out and says since when; a lost connection turns the banner
 * red (#conn[data-state=lost]) and greys every figure.
 */
(function () {
  "use strict";
  const body = document.body;
  const PAGE = body.dataset.page;
  const HOIST = body.dataset.hoist;
  const CSRF = body.dataset.csrf;
  const STALE_S = parseFloat(body.dataset.staleS || "2");
  const WATCHDOG_MS = 10000;      // the station sends its status every second: silence means not live
  const BEEP_REPEAT_MS = 5000;    // ring again while an alarm stays unacknowledged
  const COLORS = ["#4fc3f7", "#ffb74d", "#81c784", "#f06292", "#ba68c8", "#e0e0e0", "#fff176", "#90a4ae"];

  // -- small helpers -------------------------------------------------------------------------
  const $ = (sel, root) => (root || document).querySelector(sel);
  const $$ = (sel, root) => Array.from((root || document).querySelectorAll(sel));
  const fin = (x) => x !== null && x !== undefined && isFinite(x);
  const num = (x, d) => (fin(x) ? Number(x).toFixed(d) : "–");
  const signed = (x, d) => (fin(x) ? (x >= 0 ? "+" : "") + Number(x).toFixed(d) : "–");
  function clock(t, withDate) {
    if (!fin(t)) return "";
    const d = new Date(t * 1000);
    const p = (n) => String(n).padStart(2, "0");
    const hms = p(d.getHours()) + ":" + p(d.getMinutes()) + ":" + p(d.getSeconds());
    return withDate ? d.getFullYear() + "-" + p(d.getMonth() + 1) + "-" + p(d.getDate()) + " " + hms : hms;
  }
  function field(root, name) { return root.querySelector('[data-field="' + name + '"]'); }
  function setText(el, text) { if (el && el.textContent !== text) el.textContent = text; }
  function fromTemplate(id) {
    const t = document.getElementById(id);
    const frag = t.content.cloneNode(true);
    return id === "tpl-node" || id === "tpl-refused" ? frag.firstElementChild : frag.querySelector("tr");
  }

  // -- station time: the browser's clock may differ from the station's ------------------------
  let offset = 0;                              // browser seconds minus station seconds
  const stationNow = () => Date.now() / 1000 - offset;
  const noteNow = (now) => { if (fin(now)) offset = Date.now() / 1000 - now; };

  // -- the connection banner ---------------------------------------------------------------------
  const conn = $("#conn");
  let lostSince = null;
  let stoppedAt = null;
  function setConn(state, text) {
    if (!conn) return;
    conn.dataset.state = state;
    setText(conn, text);
    body.classList.toggle("not-live", state !== "live");
  }
  function markLost(why) {
    if (lostSince === null) lostSince = Date.now() / 1000;
    setConn("lost", (why || "CONNECTION LOST") + " since " + clock(lostSince) + ": the figures shown are NOT live");
    refreshAges();
  }

  /** One EventSource with a snapshot on (re)connect and a watchdog. */
  function stream(url, handlers) {
    let es = null;
    let last = Date.now();
    function open() {
      if (es) es.close();
      es = new EventSource(url);
      last = Date.now();
      for (const name of Object.keys(handlers)) {
        es.addEventListener(name, (e) => {
          last = Date.now();
          if (name === "snapshot" || name === "overview") {
            lostSince = null;
            if (stoppedAt === null) setConn("live", "live");
          }
          handlers[name](JSON.parse(e.data));
        });
      }
      es.addEventListener("session_ended", () => {      // logged out elsewhere, or idle too long
        es.close();
        markLost("SESSION ENDED");
        window.location.assign("/login?next=" + encodeURIComponent(window.location.pathname));
      });
      es.onerror = () => {
        markLost();
        if (es.readyState === EventSource.CLOSED) setTimeout(open, 3000);   // refused (e.g. logged out)
      };
    }
    setInterval(() => {
      if (Date.now() - last > WATCHDOG_MS) {            // nothing, not even the status: reconnect
        markLost("NO DATA");
        open();
      }
    }, 2000);
    open();
  }

  // -- sound: browsers start audio only after a click on the page ----------------------------------
  const banner = $("#sound-banner");
  let audio = null;
  let lastBeep = 0;
  function soundState() {
    const on = !!audio && audio.state === "running";
    body.dataset.sound = on ? "on" : "off";
    if (banner) banner.hidden = on;
    return on;
  }
  function initSound() {
    if (!banner) return;
    const AC = window.AudioContext || window.webkitAudioContext;
    if (!AC) { banner.hidden = true; return; }
    try { audio = new AC(); } catch (e) { audio = null; }
    soundState();
    $("#sound-enable").addEventListener("click", () => {
      if (!audio) audio = new AC();
      audio.resume().then(() => { soundState(); beep(0.12); });
    });
    if (audio) audio.onstatechange = soundState;
  }
  function beep(seconds) {
    if (!soundState()) { if (banner) banner.classList.add("pending"); return; }
    const t0 = audio.currentTime;
    for (const [k, f] of [[0, 880], [1, 660]]) {
      const o = audio.createOscillator();
      const g = audio.createGain();
      o.type = "square";
      o.frequency.value = f;
      g.gain.value = 0.15;
      o.connect(g).connect(audio.destination);
      o.start(t0 + k * (seconds + 0.05));
      o.stop(t0 + k * (seconds + 0.05) + seconds);
    }
    lastBeep = Date.now();
    body.dataset.beeps = String(parseInt(body.dataset.beeps || "0", 10) + 1);
  }
  function alarmSound(unacked, newRaise) {
    if (newRaise || (unacked > 0 && Date.now() - lastBeep > BEEP_REPEAT_MS)) {
      if (unacked > 0 || newRaise) beep(0.18);
    }
    if (banner) banner.classList.toggle("pending", unacked > 0 && !soundState());
  }

  // -- actions: forms posted with fetch, the result in a toast ---------------------------------------
  function toast(text, bad) {
    let t = $("#toast");
    if (!t) { t = document.createElement("div"); t.id = "toast"; t.setAttribute("role", "status"); body.appendChild(t); }
    t.textContent = text;
    t.className = bad ? "bad" : "ok";
    t.hidden = false;
    clearTimeout(toast.timer);
    toast.timer = setTimeout(() => { t.hidden = true; }, bad ? 8000 : 4000);
  }
  document.addEventListener("submit", (e) => {
    const form = e.target;
    if (!form.classList || !form.classList.contains("act")) return;
    e.preventDefault();
    if (form.dataset.confirm && !window.confirm(form.dataset.confirm)) return;
    fetch(form.action, {
      method: "POST", body: new FormData(form), credentials: "same-origin",
      headers: { "X-Requested-With": "fetch", "X-CSRF-Token": CSRF, "Accept": "application/json" },
    }).then((r) => r.json().then((j) => ({ r, j }))).then(({ r, j }) => {
      if (r.status === 401) { window.location = "/login?next=" + encodeURIComponent(location.pathname); return; }
      if (!j.ok) { toast("refused: " + (j.field ? j.field + ": " : "") + j.error, true); return; }
      toast(j.done);
      const box = form.closest("details");
      if (box) { box.open = false; form.reset(); }
    }).catch((err) => toast("not sent: " + err, true));
  });

  // -- the live page -------------------------------------------------------------------------------
  const live = { site: {}, bands: {}, hoist: {}, maxDepth: {}, charts: {}, trend: {}, unacked: 0, alarmsSeen: false };

  function ensureNode(n) {
    let panel = document.getElementById("node-" + n);
    if (panel) return panel;
    panel = fromTemplate("tpl-node");
    panel.id = "node-" + n;
    panel.dataset.node = n;
    setText($("h2", panel), "node " + n);
    const nodes = $("#nodes");
    const after = $$(".node", nodes).find((p) => parseInt(p.dataset.node, 10) > parseInt(n, 10));
    nodes.insertBefore(panel, after || $("#no-frames"));
    $("#no-frames").hidden = true;
    if (live.hoist) setTimeout(renderHoistStatus, 0);
    return panel;
  }

  function ensureRope(panel, k) {
    const tb = field(panel, "ropes");
    let row = tb.querySelector('tr[data-rope="' + k + '"]');
    if (row) return row;
    row = fromTemplate("tpl-rope");
    row.dataset.rope = k;
    setText(field(row, "rope"), String(k));
    tb.appendChild(row);
    return row;
  }

  function devBar(bar, dev, band, limit) {
    const span = 1.5 * limit;
    const pos = (x) => Math.max(0, Math.min(100, 50 + (x / span) * 50));
    const fill = $(".fill", bar);
    const b = $(".band", bar);
    $(".lim.lo", bar).style.left = pos(-limit) + "%";
    $(".lim.hi", bar).style.left = pos(limit) + "%";
    bar.dataset.dev = fin(dev) ? String(dev) : "";
    if (!fin(dev)) { fill.style.width = "0"; b.style.width = "0"; bar.className = "devbar"; return; }
    const a = pos(0), z = pos(dev);
    fill.style.left = Math.min(a, z) + "%";
    fill.style.width = Math.abs(z - a) + "%";
    if (band && fin(band.d_min) && fin(band.d_max)) {
      b.style.left = pos(band.d_min) + "%";
      b.style.width = Math.max(0.5, pos(band.d_max) - pos(band.d_min)) + "%";
      bar.dataset.band = String(band.band);
    } else {
      b.style.width = "0";
      delete bar.dataset.band;
    }
    const reach = band && fin(band.reach) ? band.reach : Math.abs(dev);
    bar.className = "devbar" + (Math.abs(dev) > limit ? " over" : (Math.abs(dev) > 0.8 * limit || reach >= limit ? " near" : ""));
  }

  /** One cylinder: the end stops at the ends of the drawn stroke, the margins inside them, the
   *  piston at its position (x > 0: pulled out by the rope, to the right) and its rod. */
  const CYL_X0 = 10, CYL_W = 180;
  function cylinder(row, r, stroke, margin) {
    const svg = field(row, "cyl");
    const val = field(row, "pos");
    if (!svg) return;
    const pos = fin(r.pos_mm) ? r.pos_mm : null;
    svg.dataset.pos = pos === null ? "" : String(pos);
    svg.classList.toggle("nostroke", !fin(stroke) || stroke <= 0);
    svg.classList.toggle("unknown", pos === null);
    let near = !!(r.near_lo || r.near_hi);
    if (fin(stroke) && stroke > 0) {
      const m = fin(margin) ? Math.min(margin, stroke / 2) : 0;
      const mw = (m / stroke) * CYL_W;
      field(row, "margin-lo").setAttribute("width", mw.toFixed(2));
      const hi = field(row, "margin-hi");
      hi.setAttribute("x", (CYL_X0 + CYL_W - mw).toFixed(2));
      hi.setAttribute("width", mw.toFixed(2));
      if (pos !== null) {
        const x = CYL_X0 + Math.max(0, Math.min(1, (pos + stroke / 2) / stroke)) * CYL_W;
        const p = field(row, "piston");
        p.setAttribute("x", (x - 3).toFixed(2));
        svg.dataset.px = x.toFixed(2);
        field(row, "rod").setAttribute("x1", x.toFixed(2));
        near = near || Math.abs(pos) >= stroke / 2 - m;
      }
    }
    svg.dataset.near = near ? "true" : "false";
    setText(val, r.pos_fault ? "FAULT: displacement" : (pos === null ? "no position" : signed(pos, 1) + " mm"));
    val.classList.toggle("bad", near || !!r.pos_fault);
  }

  function renderNode(v) {
    const panel = ensureNode(v.node);
    panel.dataset.t = v.t;
    panel.classList.toggle("no-pos", !v.positions);
    const strokes = live.site.stroke_mm || [];
    const limit = live.site.imbalance_frac || 0.1;
    const bands = live.bands[String(v.node)] || [];
    v.ropes.forEach((r, i) => {
      const row = ensureRope(panel, r.rope);
      row.classList.toggle("fault", !!r.fault);
      setText(field(row, "comp"), r.fault ? "FAULT" : num(r.comp_kN, 1) + (r.held_back ? " *" : ""));
      row.classList.toggle("held", !!r.held_back);
      field(row, "comp").title = r.held_back ? v.held_why : "";
      setText(field(row, "raw"), r.raw_kN !== null ? num(r.raw_kN, 1) : (r.raw_kpa !== null ? r.raw_kpa + " kPa" : "–"));
      const band = bands[i];
      setText(field(row, "dev"), fin(r.dev) ? signed(r.dev * 100, 1) + " %" + (band && fin(band.band) ? " ±" + num(band.band * 100, 1) : "") : "");
      setText(field(row, "range"), r.min_kN !== null ? num(r.min_kN, 1) + "..." + num(r.max_kN, 1) : "");
      devBar(field(row, "devbar"), r.dev, band, limit);
      if (v.positions) cylinder(row, r, strokes[i], live.site.margin_mm);
    });
    $$("tr.rope", field(panel, "ropes")).forEach((row) => { if (parseInt(row.dataset.rope, 10) > v.ropes.length) row.remove(); });
    const held = field(panel, "held");
    if (held) {
      setText(held, v.held_back && v.held_back.length ? "* rope " + v.held_back.join(", ") + ": " + v.held_why : "");
      held.hidden = !(v.held_back && v.held_back.length);
    }
    setText(field(panel, "sum-label"), v.partial ? "part" : "sum");
    setText(field(panel, "sum"), v.status_only ? "–" : num(v.sum_kN, 1));
    setText(field(panel, "raw-sum"), v.raw_sum_kN !== null ? num(v.raw_sum_kN, 1) : "");
    const rated = live.site.rated_load_kN;
    const load = field(panel, "load");
    const bar = field(panel, "loadbar");
    if (v.status_only) {
      setText(load, "STATUS ONLY: node not compensating");
    } else if (v.partial) {
      setText(load, "PARTIAL SUM: rope " + v.missing.join(", ") + " missing");
    } else if (fin(v.load_frac)) {
      setText(load, num(v.load_frac * 100, 0) + " % of rated " + num(rated, 0) + " kN");
    } else {
      setText(load, "");
    }
    load.classList.toggle("bad", !!v.partial || v.status_only || (fin(v.load_frac) && v.load_frac > 1));
    const frac = fin(v.load_frac) ? v.load_frac : 0;
    $(".fill", bar).style.width = Math.min(100, frac / 1.2 * 100) + "%";
    $(".lim", bar).style.left = (1 / 1.2 * 100) + "%";
    bar.classList.toggle("over", frac > 1);
    setText(field(panel, "depth"), num(v.depth_m, 1) + " m");
    setText(field(panel, "speed"), signed(v.speed_m_s, 2) + " m/s");
    const bat = field(panel, "battery");
    setText(bat, num(v.battery_v, 2) + " V" + (v.battery_low ? " LOW" : ""));
    bat.classList.toggle("bad", !!v.battery_low);
    setText(field(panel, "oil"), num(v.oil_c, 1) + " °C");
    setText(field(panel, "flags"), (v.flags || []).join(" "));
    // the shaft: the cage at its depth, the shaft as configured or as deep as seen
    const deepest = Math.max(live.maxDepth[v.node] || 0, fin(v.depth_m) ? v.depth_m : 0);
    live.maxDepth[v.node] = deepest;
    const shaft = live.site.shaft_m || Math.max(deepest * 1.05, 1);
    const y = 6 + Math.max(0, Math.min(1, (v.depth_m || 0) / shaft)) * (188 - 12);
    field(panel, "cage").setAttribute("y", y.toFixed(1));
    setText(field(panel, "shaft-bottom"), num(shaft, 0));
    refreshAge(panel);
  }

  function refreshAge(panel) {
    const t = parseFloat(panel.dataset.t);
    if (!fin(t)) return;
    const age = stationNow() - t;
    const marker = field(panel, "stale");
    const notLive = lostSince !== null || stoppedAt !== null;
    const stale = age > STALE_S || notLive;
    panel.classList.toggle("stale", stale);
    panel.dataset.stale = stale ? "true" : "false";
    if (marker) {
      marker.hidden = !stale;
      marker.dataset.stale = stale ? "true" : "false";
      if (stale) {
        setText(marker, notLive ? "NOT LIVE: last frame " + clock(t) + (lostSince ? ", connection lost " + clock(lostSince) : ", station stopped")
          : "STALE since " + clock(t) + " (no frame for " + num(age, 0) + " s)");
      }
    }
    setText(field(panel, "age"), "last frame " + (age < 100 ? num(Math.max(0, age), 1) : num(age, 0)) + " s ago");
  }
  function refreshAges() { $$(".node[data-node], .card-node[data-t]").forEach(refreshAge); }

  const STATE_TEXT = {
    unacknowledged: "NEW, not acknowledged", acknowledged: "acknowledged", rtn_unacknowledged: "returned to normal, not acknowledged",
    shelved: "shelved", out_of_service: "out of service", suppressed: "suppressed (its sensor failed)",
  };
  function stateText(a) {
    return (STATE_TEXT[a.state] || a.state) + (a.state === "acknowledged" && a.acked_by ? " by " + a.acked_by : "");
  }
  function setAlarmId(row, id) {
    row.dataset.alarmId = id;
    $$('[data-field="alarm-id"]', row).forEach((i) => { i.value = id; });
    $$("button[data-alarm-id]", row).forEach((b) => { b.dataset.alarmId = id; });
  }

  /** Each node's standing status (the imbalance its seals can hide): status, not an alarm. */
  function renderHoistStatus() {
    $$(".node[data-node]").forEach((panel) => {
      const st = live.hoist[panel.dataset.node];
      const el = field(panel, "hoist-status");
      if (!el) return;
      el.hidden = !(st && st.text);
      setText(el, st && st.text ? "hoist: " + st.text : "");
    });
  }

  function renderAlarms(al) {
    live.bands = al.bands || {};
    if (al.hoist) { live.hoist = al.hoist; renderHoistStatus(); }
    const tb = $("#alarm-rows");
    if (!tb) return;
    const have = new Map($$("tr[data-alarm-id]", tb).map((r) => [r.dataset.alarmId, r]));
    const rows = al.active.map((a) => {
      let row = have.get(a.id);
      if (!row) { row = fromTemplate("tpl-alarm"); setAlarmId(row, a.id); }
      have.delete(a.id);
      row.className = "alarm p" + a.priority + (a.warning ? " warning" : "") + " " + a.state;
      row.dataset.state = a.state;
      row.dataset.priority = a.priority;
      row.dataset.firstOut = a.first_out ? "true" : "false";
      field(row, "first-out").hidden = !a.first_out;
      setText(field(row, "priority"), "P" + a.priority);
      setText(field(row, "text"), a.text);
      setText(field(row, "state"), stateText(a));
      setText(field(row, "raised"), clock(a.raised_s));
      const ack = field(row, "ack-slot");
      if (ack) ack.hidden = !a.latched;
      return row;
    });
    have.forEach((r) => r.remove());
    const current = $$("tr[data-alarm-id]", tb);
    if (current.length !== rows.length || rows.some((r, i) => current[i] !== r)) rows.forEach((r) => tb.appendChild(r));
    const unacked = al.active.filter((a) => a.latched).length;
    $("#no-alarms").hidden = al.active.length > 0;
    setText($("#alarm-summary"), al.active.length ? al.active.length + " active, " + unacked + " not acknowledged" : "");
    $("#alarms-panel").dataset.unacked = unacked;
    const ackAll = $("#ack-all-form");
    if (ackAll) ackAll.hidden = unacked === 0;
    $("#alarms-panel").classList.toggle("alarming", al.active.some((a) => !a.warning));
    // hidden: shelved, out of service, suppressed
    const hb = $("#hidden-rows");
    const hhave = new Map($$("tr[data-alarm-id]", hb).map((r) => [r.dataset.alarmId, r]));
    al.hidden.forEach((a) => {
      let row = hhave.get(a.id);
      if (!row) { row = fromTemplate("tpl-hidden"); setAlarmId(row, a.id); hb.appendChild(row); }
      hhave.delete(a.id);
      row.dataset.state = a.state;
      setText(field(row, "text"), a.text);
      setText(field(row, "state"), stateText(a));
      setText(field(row, "note"), (a.note || "") + (a.shelved_until ? " until " + clock(a.shelved_until) : ""));
      const un = field(row, "unshelve-slot");
      if (un) un.hidden = a.state !== "shelved";
      const ret = field(row, "return-slot");
      if (ret) ret.hidden = a.state !== "out_of_service";
    });
    hhave.forEach((r) => r.remove());
    setText($("#hidden-count"), String(al.hidden.length));
    live.unacked = unacked;
    alarmSound(unacked, false);
  }

  function renderStatus(st) {
    noteNow(st.now);
    const tb = $("#links tbody");
    if (tb) {
      const have = new Map($$("tr[data-receiver]", tb).map((r) => [r.dataset.receiver, r]));
      (st.receivers || []).forEach((r) => {
        let row = have.get(r.name);
        if (!row) {
          row = document.createElement("tr");
          row.dataset.receiver = r.name;
          const th = document.createElement("th"); th.textContent = r.name;
          const td = document.createElement("td"); td.dataset.field = "figures";
          row.append(th, td);
          tb.appendChild(row);
        }
        have.delete(r.name);
        row.dataset.connected = r.connected ? "true" : "false";
        row.classList.toggle("bad", !r.connected);
        setText(field(row, "figures"), r.figures);
      });
      have.forEach((r) => r.remove());
    }
    setText($("#merge"), (st.merge || "") + (st.authenticated ? "" : "  NO KEY: not authenticated") +
      (st.dropped ? "  HOST OVERLOADED: " + st.dropped + " frames not processed" : ""));
    setText($("#faults"), Object.entries(st.faults || {}).map(([k, v]) => k + ": " + v).join("; "));
    const box = $("#refused");
    if (box) {
      const want = st.refused || {};
      $$(".refused", box).forEach((el) => { if (!(el.dataset.node in want)) el.remove(); });
      Object.entries(want).forEach(([n, v]) => {
        let el = box.querySelector('.refused[data-node="' + n + '"]');
        if (!el) {
          el = fromTemplate("tpl-refused");
          el.dataset.node = n;
          const inp = field(el, "node"); if (inp) inp.value = n;
          const b = $("button", el); if (b) b.dataset.node = n;
          box.appendChild(el);
        }
        setText(field(el, "text"), "NODE " + n + " REFUSED: boot counter went back " + v[0] + " → " + v[1] +
          ": a replay, or the node lost its counter (flash wiped or replaced)");
      });
    }
  }

  function addEvent(e, prepend) {
    const ul = $("#events");
    if (!ul) return;
    const li = document.createElement("li");
    li.dataset.action = e.action;
    li.dataset.alarm = e.alarm;
    const t = document.createElement("time"); t.textContent = clock(e.time_s);
    const b = document.createElement("b"); b.textContent = e.action;
    li.append(t, " ", b, " " + e.message);
    if (prepend) ul.insertBefore(li, ul.firstChild); else ul.appendChild(li);
    while (ul.children.length > 50) ul.lastChild.remove();
  }

  // -- trend charts (uPlot) ---------------------------------------------------------------------
  function ropeSeries(n, dash) {
    const s = [{}];
    for (let i = 0; i < n; i++) s.push({ label: "rope " + (i + 1), stroke: COLORS[i % COLORS.length], width: 1.5, dash: dash, spanGaps: false });
    return s;
  }
  function makeChart(el, series, data, opts) {
    if (!window.uPlot || !el) return null;
    const width = Math.max(300, el.clientWidth || 600);
    const o = Object.assign({
      width: width, height: (opts && opts.height) || 200, series: series,
      scales: { x: { time: !(opts && opts.seconds) }, y: { dir: opts && opts.down ? -1 : 1 } },
      axes: [{ stroke: "#bbb", grid: { stroke: "#333" } }, { stroke: "#bbb", grid: { stroke: "#333" }, label: (opts && opts.ylabel) || "kN" }],
      cursor: { drag: { x: true, y: false } },
      legend: { live: true },
      hooks: (opts && opts.hooks) || {},
    }, {});
    const u = new uPlot(o, data, el);
    window.addEventListener("resize", () => u.setSize({ width: Math.max(300, el.clientWidth), height: o.height }));
    return u;
  }

  function liveTrend(n, cols) {
    const panel = document.getElementById("node-" + n);
    const el = panel ? field(panel, "trend") : $("#trend-chart");
    const ropes = cols.ropes.length;
    const data = [cols.t.slice()].concat(cols.ropes.map((r) => r.slice()));
    let c = live.charts[n];
    if (c && c.ropes !== ropes) { c.u.destroy(); c = null; }
    if (!c) {
      const st = { follow: true, ropes: ropes, data: data, dirty: false };
      st.u = makeChart(el, ropeSeries(ropes), data, {
        height: 180, hooks: { setSelect: [() => { st.follow = false; }] },
      });
      if (!st.u) return;
      st.u.over.addEventListener("dblclick", () => { st.follow = true; });
      live.charts[n] = st;
    } else {
      c.data = data;
      c.u.setData(data, c.follow);
    }
  }
  function trendPoint(v) {
    const c = live.charts[v.node];
    if (!c) { if (!v.status_only) liveTrend(v.node, { t: [v.t], ropes: v.ropes.map((r) => [r.comp_kN]) }); return; }
    if (v.ropes.length !== c.ropes) return;
    const last = c.data[0].length ? c.data[0][c.data[0].length - 1] : null;
    if (last !== null && v.t - last > STALE_S) {           // frames missed: a gap, not a line across it
      c.data[0].push((v.t + last) / 2);
      v.ropes.forEach((r, i) => c.data[i + 1].push(null));
    }
    c.data[0].push(v.t);
    v.ropes.forEach((r, i) => c.data[i + 1].push(r.comp_kN));
    const cut = v.t - 600;
    let k = 0;
    while (k < c.data[0].length && c.data[0][k] < cut) k++;
    if (k) c.data.forEach((col) => col.splice(0, k));
    c.dirty = true;
  }
  setInterval(() => {
    for (const c of Object.values(live.charts)) if (c.dirty && c.u) { c.dirty = false; c.u.setData(c.data, c.follow); }
  }, 1000);

  function startLive() {
    const root = $("#live");
    live.site = JSON.parse(root.dataset.site || "{}");
    initSound();
    stream("/hoist/" + encodeURIComponent(HOIST) + "/stream", {
      snapshot(s) {
        noteNow(s.now);
        stoppedAt = s.stopped ? s.now : null;
        live.site = s.site;
        renderAlarms(s.alarms);
        Object.values(s.nodes).forEach(renderNode);
        if (s.status && s.status.receivers) renderStatus(s.status);
        const ul = $("#events");
        if (ul) { ul.innerHTML = ""; s.events.slice().reverse().forEach((e) => addEvent(e, false)); }
        Object.entries(s.trend || {}).forEach(([n, cols]) => liveTrend(n, cols));
        live.alarmsSeen = true;
        refreshAges();
      },
      frame(v) { renderNode(v); if (!v.status_only) trendPoint(v); },
      alarms: renderAlarms,
      hoist(h) { live.hoist = h; renderHoistStatus(); },
      status: renderStatus,
      event(e) {
        addEvent(e, true);
        if (e.action === "raise" && e.annunciated) alarmSound(live.unacked, true);
      },
      stop(s) { stoppedAt = s.now; setConn("lost", "THE STATION STOPPED at " + clock(s.now) + ": the figures shown are NOT live"); refreshAges(); },
      dropped() { markLost("TOO SLOW: reconnecting"); },
    });
    setInterval(refreshAges, 500);
  }

  // -- the overview -------------------------------------------------------------------------------
  function renderCard(s) {
    const card = document.querySelector('.hoist-card[data-hoist="' + s.hoist + '"]');
    if (!card) return;
    noteNow(s.now);
    card.dataset.unacked = s.unacked;
    card.dataset.active = s.active;
    card.classList.toggle("alarming", s.active > s.warnings);
    card.classList.toggle("warning", s.active > 0 && s.active === s.warnings);
    setText($(".alarm-count", card), s.active ? s.active + " alarm" + (s.active !== 1 ? "s" : "") +
      (s.unacked ? ", " + s.unacked + " not acknowledged" : "") : "no alarms");
    const ul = $(".alarm-texts", card);
    ul.innerHTML = "";
    s.alarms.forEach((t) => { const li = document.createElement("li"); li.textContent = t; ul.appendChild(li); });
    const box = $(".card-nodes", card);
    Object.entries(s.nodes).forEach(([n, v]) => {
      let p = box.querySelector('.card-node[data-node="' + n + '"]');
      const none = $(".none", box); if (none) none.remove();
      if (!p) {
        p = document.createElement("p");
        p.className = "card-node";
        p.dataset.node = n;
        p.innerHTML = 'node <span data-field="n"></span>: <span class="load" data-field="sum"></span>, <span data-field="depth"></span>, ' +
          '<span class="age" data-field="age"></span> <span class="stale-marker" data-field="stale" data-stale="false" hidden></span>';
        setText(field(p, "n"), n);
        box.appendChild(p);
      }
      p.dataset.t = v.t;
      setText(field(p, "sum"), (v.partial ? "PARTIAL " : "") + num(v.sum_kN, 1) + " kN" + (s.rated_load_kN ? " of " + num(s.rated_load_kN, 0) + " kN" : ""));
      setText(field(p, "depth"), num(v.depth_m, 1) + " m");
      refreshAge(p);
    });
    return s.unacked;
  }
  function startOverview() {
    initSound();
    const unacked = {};
    const total = () => Object.values(unacked).reduce((a, b) => a + b, 0);
    stream("/overview/stream", {
      overview(list) { list.forEach((s) => { unacked[s.hoist] = renderCard(s); }); alarmSound(total(), false); },
      summary(s) {
        const before = unacked[s.hoist] || 0;
        unacked[s.hoist] = renderCard(s);
        alarmSound(total(), unacked[s.hoist] > before);
      },
    });
    setInterval(refreshAges, 500);
  }

  // -- trends: live (the last 10 minutes) or the log (hours) -------------------------------------------
  function startTrends() {
    const nodeSel = $("#trend-node");
    const status = $("#trend-status");
    const chartEl = $("#trend-chart");
    const depthEl = $("#trend-depth");
    let mode = "live";
    let hours = 1;
    let u = null, ud = null;
    let snapTrend = {};
    let liveData = null;
    let liveDirty = false;
    const node = () => nodeSel ? nodeSel.value : null;

    function draw(t, ropes, depth, isLive) {
      const data = [t].concat(ropes);
      if (u) { u.destroy(); u = null; }
      if (ud) { ud.destroy(); ud = null; }
      u = makeChart(chartEl, ropeSeries(ropes.length), data, {
        height: 320, hooks: { setSelect: [(self) => {
          if (self.select.width < 4 || mode === "live") return;
          const t0 = self.posToVal(self.select.left, "x"), t1 = self.posToVal(self.select.left + self.select.width, "x");
          fetchHistory(t0, t1);
        }] },
      });
      if (depth) {
        ud = makeChart(depthEl, [{}, { label: "depth m", stroke: "#aaa", width: 1 }], [t, depth], { height: 120, ylabel: "m", down: true });
      }
      liveData = isLive ? data : null;
    }
    function fetchHistory(t0, t1) {
      const q = new URLSearchParams({ node: node() });
      if (t0 !== undefined) { q.set("t0", t0); q.set("t1", t1); } else { q.set("hours", hours); }
      setText(status, "reading the log…");
      fetch("/hoist/" + encodeURIComponent(HOIST) + "/history.json?" + q, { credentials: "same-origin" })
        .then((r) => r.json().then((j) => ({ r, j }))).then(({ r, j }) => {
          if (!r.ok) { setText(status, "refused: " + (j.field ? j.field + ": " : "") + j.error); return; }
          setText(status, j.frames + " frames from " + clock(j.t0, true) + " to " + clock(j.t1, true) +
            (j.bucket_s > 0.2 ? ", averaged over " + num(j.bucket_s, j.bucket_s < 10 ? 1 : 0) + " s" : ""));
          draw(j.t, j.ropes, j.depth_m, false);
        }).catch((e) => setText(status, "not read: " + e));
    }
    function showLive() {
      const cols = snapTrend[node()];
      setText(status, cols ? "live: the last 10 minutes at frame rate" : "no frames from this node yet");
      if (cols) draw(cols.t.slice(), cols.ropes.map((r) => r.slice()), null, true);
    }
    $$("#trend-ranges button").forEach((b) => b.addEventListener("click", () => {
      $$("#trend-ranges button").forEach((x) => x.classList.toggle("here", x === b));
      if (b.dataset.range === "live") { mode = "live"; showLive(); } else { mode = "log"; hours = parseFloat(b.dataset.hours); fetchHistory(); }
    }));
    if (nodeSel) nodeSel.addEventListener("change", () => (mode === "live" ? showLive() : fetchHistory()));
    initSound();
    stream("/hoist/" + encodeURIComponent(HOIST) + "/stream", {
      snapshot(s) {
        noteNow(s.now);
        snapTrend = s.trend || {};
        if (nodeSel) {
          Object.keys(s.nodes).forEach((n) => {
            if (!$$("option", nodeSel).some((o) => o.value === n)) { const o = document.createElement("option"); o.value = o.textContent = n; nodeSel.appendChild(o); }
          });
        }
        if (mode === "live") showLive();
      },
      frame(v) {
        if (v.status_only) return;
        const cols = snapTrend[v.node] || (snapTrend[v.node] = { t: [], ropes: v.ropes.map(() => []) });
        cols.t.push(v.t); v.ropes.forEach((r, i) => cols.ropes[i] && cols.ropes[i].push(r.comp_kN));
        if (mode === "live" && String(v.node) === node() && liveData && liveData.length === v.ropes.length + 1) {
          liveData[0].push(v.t); v.ropes.forEach((r, i) => liveData[i + 1].push(r.comp_kN));
          liveDirty = true;
        }
      },
      alarms(al) { alarmSound(al.active.filter((a) => a.latched).length, false); },
      status(st) { noteNow(st.now); },
      event(e) { if (e.action === "raise" && e.annunciated) alarmSound(1, true); },
      stop() { markLost("THE STATION STOPPED"); },
    });
    setInterval(() => { if (liveDirty && u && liveData) { liveDirty = false; u.setData(liveData); } }, 1000);
  }

  // -- a trip's chart ----------------------------------------------------------------------------
  function startTrip() {
    const el = $("#trip-chart");
    if (!el) return;
    fetch(el.dataset.src, { credentials: "same-origin" }).then((r) => r.json()).then((j) => {
      const n = j.comp.length;
      const series = [{}];
      for (let i = 0; i < n; i++) series.push({ label: "rope " + (i + 1) + " comp", stroke: COLORS[i % COLORS.length], width: 1.5 });
      for (let i = 0; i < n; i++) series.push({ label: "rope " + (i + 1) + " raw", stroke: COLORS[i % COLORS.length], width: 1, dash: [6, 4] });
      makeChart(el, series, [j.t].concat(j.comp, j.raw), { height: 340, seconds: true });
      makeChart($("#trip-depth"), [{}, { label: "depth m", stroke: "#aaa", width: 1 }], [j.t, j.depth_m], { height: 120, seconds: true, ylabel: "m", down: true });
    }).catch(() => { el.textContent = "the chart could not be read"; });
  }

  if (PAGE === "live") startLive();
  else if (PAGE === "overview") startOverview();
  else if (PAGE === "trends") startTrends();
  else if (PAGE === "trip") startTrip();
})();
