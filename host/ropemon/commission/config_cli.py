"""`ropemon config SITE.toml [--out node.json]`: the node config for a site.

SITE.toml -> ropemon.commission.site (validated site, `physical` section with the pipe loss
tables, the friction fit and the optional hydraulic compliance fit) ->
ropemon.commission.nodejson.make_node_json (fixed-point `node` section with the node's id
and key, every integer proved within +-2**30, schema, CRC, SHA-256) -> node.json, written
with mode 0600 (it holds the key). A site file, friction or compliance fit that cannot be
used is refused with the field and the reason, exit 1. It prints what the site is commissioned with, including the imbalance
the seals can hide (`deviation_cover`: the hoist's standing status, which the station shows
on every face) and the stroke margins (`stroke_lines`).
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from ropemon.commission.nodejson import write_node_json
from ropemon.commission.site import (Site, SiteError, in_file, load_site, physical_from_site, read_compliance,
                                     read_friction)


def node_json_from_site(site: Site, friction: dict[str, Any] | None = None,
                        compliance: dict[str, Any] | None = None) -> dict[str, Any]:
    """The complete node.json document for a site (friction and compliance from its
    [friction] and [compliance] files unless given)."""
    from ropemon.commission.nodejson import make_node_json

    physical = physical_from_site(site, friction, compliance)
    try:
        return make_node_json(physical, node_id=site.node_id, key=site.key)
    except ValueError as e:
        # nodejson names the physical field; say which site input it came from.
        raise SiteError(f"{e} (node config built from {site.path})") from None


# The verdicts of the fits' own checks (`check` of fit-compliance --site and of fit-friction):
# "worse" is refused unless the override is given, "marginal" and "unchecked" are warned, as is a
# fit without a check (fit-compliance without --site, a fit-friction before it checked its fits).
CHECK_VERDICTS = {"compliance": ("ok", "marginal", "unchecked", "worse"), "friction": ("ok", "marginal", "worse")}
OVERRIDE = {"compliance": "--accept-unchecked-compliance", "friction": "--accept-unchecked-friction"}


def _check_figure(table: dict[str, Any], key: str, field: str, lo: float, hi: float, unit: str = "") -> float | None:
    """table[key] (None when absent or null), a number within lo..hi; SiteError naming `field`."""
    v = table.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
        raise SiteError(f"{field}: must be a number within {lo:g}..{hi:g}{unit}, got {v!r}")
    return float(v)


def fit_check(fit: Any, what: str, accept: bool = False) -> list[str]:
    """The warnings for a fit's own check (`what`: "compliance" or "friction"); SiteError naming
    the field for a check that cannot be read, or one whose verdict refused the fit ("worse")
    unless `accept` (the override flag: then a warning)."""
    if not isinstance(fit, dict):
        return []
    name = what
    if "check" not in fit:
        if what == "compliance":
            return ["compliance: the fit carries no check (fitted without --site): it was not compared with a "
                    "known load; refit with `ropemon fit-compliance ... --site SITE.toml` (docs/commissioning.md, "
                    "\"The fit's own check\")"]
        return ["friction: the fit carries no check on the bed's force (made before fit-friction checked its "
                "fits): rerun `ropemon fit-friction` on the bed's record"]
    chk = fit["check"]
    if not isinstance(chk, dict):
        raise SiteError(f"{name}.check: must be an object, got {type(chk).__name__}")
    verdict = chk.get("verdict")
    if verdict not in CHECK_VERDICTS[what]:
        raise SiteError(f"{name}.check.verdict: must be one of {', '.join(CHECK_VERDICTS[what])}, got {verdict!r}")
    if what == "compliance":
        harm = _check_figure(chk, "worst_harm_frac", f"{name}.check.worst_harm_frac", -1.0, 1.0)
        tol = _check_figure(chk, "tolerance_frac", f"{name}.check.tolerance_frac", 0.0, 1.0)
        figures = ("" if harm is None else f"the total at a rest of known load {harm * 100:.2f} % of the load "
                   f"farther off than without it" + ("" if tol is None else f", tolerance {tol * 100:.2f} %"))
    else:
        worst = chk.get("worst")
        if worst is not None and not isinstance(worst, dict):
            raise SiteError(f"{name}.check.worst: must be an object, got {type(worst).__name__}")
        harm = None if worst is None else _check_figure(worst, "harm_N", f"{name}.check.worst.harm_N", -1e9, 1e9,
                                                        " N")
        tol = _check_figure(chk, "tolerance_N", f"{name}.check.tolerance_N", 0.0, 1e9, " N")
        figures = ("" if harm is None else f"{harm:.0f} N rms more error on the bed's force than raw p x A"
                   + ("" if tol is None else f", tolerance {tol:.0f} N"))
    figures = f" ({figures})" if figures else ""
    if verdict == "worse":
        msg = (f"{name}.check.verdict: 'worse': the fit's own check found it makes the node read worse than "
               f"without it{figures}")
        if not accept:
            raise SiteError(msg + f"; refused (fit again, or give {OVERRIDE[what]} to use it anyway)")
        return [msg + f"; used anyway ({OVERRIDE[what]})"]
    if verdict == "marginal":
        return [f"{name}: the fit's own check found it no better than without it{figures}: accepted"]
    if verdict == "unchecked":
        return [f"{name}: the fit's own check found no rest of known load in its recording: it was not compared "
                "with a known load"]
    return []


def site_warnings(site: Site, doc: dict[str, Any], friction_doc: dict[str, Any] | None) -> list[str]:
    """Things that are allowed but that the commissioning engineer should look at."""
    out = []
    if friction_doc and isinstance(friction_doc.get("pressure_range_MPa"), list):
        lo, hi = friction_doc["pressure_range_MPa"]
        if hi < site.rated_pressure_MPa:
            out.append(f"friction: the test bed went up to {hi:g} MPa, below the rated-tension pressure "
                       f"{site.rated_pressure_MPa:.2f} MPa: above it the node holds the lines at their "
                       f"{hi:g} MPa values")
        for w in friction_doc.get("warnings", []):
            out.append(f"friction fit: {w}")
    fitted_s0 = (friction_doc or {}).get("sigma0")
    used_s0 = doc["physical"]["friction"]["sigma0"]
    if isinstance(fitted_s0, (int, float)) and fitted_s0 > used_s0:
        out.append(f"friction: the fitted sigma0 {fitted_s0:.3g} N/m is stiffer than the node represents at "
                   f"this sample rate and piston speed limit; using {used_s0:.3g} N/m (pre-sliding below "
                   "the displacement channel's resolution either way)")
    cover = deviation_cover(doc["physical"], site.hoist.empty_load_N / site.hoist.ropes,
                            site.hoist.rated_rope_tension_N)
    if cover is not None and max(cover["empty_reach"], cover["rated_reach"]) >= cover["limit"]:
        where = [f"{cover[k + '_reach']:.1%} {what}" for k, what in
                 (("empty", "with the cage empty at the pithead"), ("rated", "at the rated rope tension"))
                 if cover[k + "_reach"] >= cover["limit"]]
        out.append(
            f"hidden imbalance: the seals can hide an imbalance of up to {' and '.join(where)}, beyond the "
            f"{cover['limit']:.0%} limit: this instrument cannot show a rope within that band to be within the "
            "limit. The station shows it as the hoist's standing status on every face (not an alarm); fit "
            "lower-friction seals or check the rope tensions periodically by other means (docs/commissioning.md, "
            "\"The imbalance the seals can hide\")")
    out += stroke_warnings(site)
    if site.sensors.temperature is None:
        temps = site.oil.table_temps_C
        out.append(f"oil: no temperature input: losses are compensated at {site.oil.temp_assumed_C:g} C; "
                   f"the table covers {temps[0]:g}..{temps[-1]:g} C for a node with an input")
    return out


def stroke_warnings(site: Site) -> list[str]:
    """A displacement transmitter that cannot read into a stroke-limit band: the node reads a
    4-20 mA channel from 3.6 to 21 mA (NAMUR NE43), beyond is the channel's fault, so a piston
    in a band beyond that shows as a transmitter fault, not as a stroke limit."""
    out = []
    for i, (cyl, ch) in enumerate(zip(site.cylinders, site.sensors.displacement)):
        lo, hi = sorted(ch.range_from_mid_m)
        span = hi - lo
        reach = (lo - span * 0.4 / 16, hi + span / 16) if ch.counts_hi > ch.counts_lo else \
            (lo - span / 16, hi + span * 0.4 / 16)
        half, m = cyl.stroke_m / 2, cyl.stroke_margin_m
        for end, band, readable, ok in (("retracted", -half + m, reach[0], reach[0] <= -half + m),
                                        ("extended", half - m, reach[1], reach[1] >= half - m)):
            if not ok:
                out.append(f"stroke: rope {i + 1}'s displacement transmitter reads only to {readable * 1e3:+.1f} mm "
                           f"from mid-stroke, short of the {end} end's stroke-limit band (from {band * 1e3:+.1f} mm): "
                           "a piston there shows as the transmitter's fault, not as a stroke limit")
    return out


def deviation_cover(physical: dict[str, Any], empty_rope_n: float, rated_rope_n: float) -> dict[str, float] | None:
    """The imbalance the seals can hide (`ropemon.station.uncertainty.hidden_reach`, the figure the
    station shows as the hoist's standing status), with the ropes equal at the empty cage's and at
    the rated rope tension, and the seal's friction bound S of the first rope there; None without
    friction lines."""
    from ropemon.station.uncertainty import BandParams, hidden_reach

    band = BandParams.from_physical(physical)
    if band is None:
        return None
    out: dict[str, float] = {"limit": float(physical.get("imbalance_frac", 0.1))}
    for name, t in (("empty", empty_rope_n), ("rated", rated_rope_n)):
        out[f"{name}_rope_N"] = t
        out[f"{name}_s_N"] = band.limits(t / band.areas_m2[0] / 1000.0)[0]
        out[f"{name}_reach"] = hidden_reach(band, t)
    return out


def cover_lines(cover: dict[str, float] | None) -> list[str]:
    """The printout of `deviation_cover`: what the seals can hide, at the empty and the rated
    rope tension, beside the limit."""
    if cover is None:
        return ["hidden imbalance: not known (no friction lines)"]
    return [f"hidden imbalance (the hoist's standing status, shown on every face): with no rope's seal seen "
            f"sliding, the seals can hold +-{cover['empty_s_N'] / 1e3:.1f} kN a rope and hide an imbalance of "
            f"up to {cover['empty_reach']:.1%} with the cage empty at the pithead "
            f"({cover['empty_rope_N'] / 1e3:.1f} kN a rope), +-{cover['rated_s_N'] / 1e3:.1f} kN and up to "
            f"{cover['rated_reach']:.1%} at the rated rope tension ({cover['rated_rope_N'] / 1e3:.1f} kN); "
            f"the limit is {cover['limit']:.0%}"]


def stroke_lines(ph: dict[str, Any]) -> list[str]:
    """The printout of the stroke: per distinct stroke, the end stops, the margin and where its
    band starts each side, and the travel tolerance (positions from mid-stroke, x > 0 pulled out)."""
    from ropemon.station.physical import Physical

    p = Physical.from_dict(ph)
    if p.stroke_m is None:
        return ["stroke: not known (no stroke_m): no stroke limit is checked"]
    m, tol = p.stroke_margin, p.travel_tolerance
    out = []
    for s in sorted(set(p.stroke_m)):
        ropes = [i + 1 for i, x in enumerate(p.stroke_m) if x == s]
        which = "every rope" if len(ropes) == p.ropes else "rope " + ", ".join(map(str, ropes))
        out.append(f"stroke {s * 1e3:.0f} mm ({which}): end stops at -{s / 2 * 1e3:.1f} and +{s / 2 * 1e3:.1f} mm "
                   f"from mid-stroke; margin {m * 1e3:.1f} mm: the stroke-limit band starts at "
                   f"{(-s / 2 + m) * 1e3:+.1f} mm (retracted) and {(s / 2 - m) * 1e3:+.1f} mm (extended); "
                   f"travel tolerance {tol * 1e3:.1f} mm: a reading beyond +-{(s / 2 + tol) * 1e3:.1f} mm is "
                   "the displacement channel's fault")
    return out


def describe(site: Site, doc: dict[str, Any]) -> str:
    ph = doc["physical"]
    loss = ph["loss"]
    i_assumed = loss["temps_C"].index(ph["oil_temp_assumed_C"])
    q_max = loss["flow_m3_s"][-1]
    worst = max(r[i_assumed][-1] for r in loss["dp_Pa"])
    h = site.hoist
    k = ph.get("hydraulic_compliance_m_per_Pa")
    hydraulic = ([] if k is None else
                 [f"hydraulic compliance {', '.join(f'{x * 1e12:.0f}' for x in k)} um/MPa per rope, "
                  f"pressure noise {ph['pressure_noise_Pa'] / 1e3:.1f} kPa rms"
                  + (f", displacement noise {ph['displacement_noise_m'] * 1e6:.1f} um rms"
                     if "displacement_noise_m" in ph else "")
                  + (f", bounce at the pithead {ph['bounce_hz']:.2f} Hz" if "bounce_hz" in ph
                     else ", bounce not measured (the node's default)")
                  + (", for the oil balance only: the seal observer runs without it (the pistons kept their "
                     "lines over too little of the commissioning wind)" if ph.get("observer_compliance") is False
                     else "")
                  + (f", play {ph['friction_play_sigmas']:g} sigma (SITE.toml)" if site.play_sigmas is not None
                     else "")
                  + ((", noise following off (SITE.toml)" if site.noise_follow_s == 0 else
                      f", noise followed over {site.noise_follow_s:g} s (SITE.toml)")
                     if site.noise_follow_s is not None else "")])
    return "\n".join([
        f"site {site.name}: node {doc['node']['node_id']}, {ph['ropes']} ropes, {ph['sample_hz']} Hz sampling, "
        f"{ph['frame_hz']} Hz frames",
        f"rated rope tension {h.rated_rope_tension_N / 1e3:.1f} kN = {site.rated_pressure_MPa:.2f} MPa; "
        f"empty cage at the pithead {h.empty_load_N / 1e3:.1f} kN, cage alone {h.conveyance_weight_N / 1e3:.1f} kN: "
        f"the host's SLACK alarm below "
        f"{ph['slack_frac'] * ph['conveyance_weight_N'] / ph['ropes'] / 1e3:.1f} kN per rope",
        f"pipe loss at {q_max * 6e4:.1f} L/min and {ph['oil_temp_assumed_C']:g} C: up to {worst / 1e6:.3f} MPa "
        f"({worst * min(ph['cylinder_area_m2']) / 1e3:.2f} kN of rope tension)",
        *hydraulic,
        *cover_lines(deviation_cover(ph, h.empty_load_N / h.ropes, h.rated_rope_tension_N)),
        *stroke_lines(ph),
        f"config CRC 0x{doc['crc']:04x}, schema {doc['schema']}",
    ])


def add_arguments(p) -> None:
    p.add_argument("site", metavar="SITE.toml", help="site description (docs/commissioning.md)")
    p.add_argument("--out", default="node.json", help="node config to write (default: node.json)")
    p.add_argument("--friction", metavar="FRICTION.json",
                   help="friction fit to use instead of the site's [friction] file")
    p.add_argument("--compliance", metavar="COMPLIANCE.json",
                   help="hydraulic compliance fit to use instead of the site's [compliance] file")
    p.add_argument("--accept-unchecked-compliance", action="store_true",
                   help="use a compliance fit whose own check found it makes the node read worse (warned)")
    p.add_argument("--accept-unchecked-friction", action="store_true",
                   help="use a friction fit whose own check on the bed found it reads worse than raw p x A (warned)")


def run(args) -> int:
    friction = None
    try:
        site = load_site(args.site)
    except SiteError as e:
        print(f"config: error: {in_file(e, args.site)}", file=sys.stderr)
        return 1
    fpath = Path(args.friction) if args.friction else site.friction_path
    cpath = Path(args.compliance) if args.compliance else site.compliance_path
    try:
        friction_doc = None
        if fpath is not None:
            friction_doc = read_friction(fpath)
            friction = friction_doc
        compliance = read_compliance(cpath) if cpath is not None else None
        checks = fit_check(friction, "friction", getattr(args, "accept_unchecked_friction", False))
        checks += fit_check(compliance, "compliance", getattr(args, "accept_unchecked_compliance", False))
        doc = node_json_from_site(site, friction, compliance if args.compliance else None)
    except SiteError as e:  # a fault of the fit files is named with the file (of SITE.toml, with the field)
        fits = {"friction": fpath if friction is not None else None, "compliance": cpath}
        path = next((p for k, p in fits.items() if p and (str(e).startswith(k + ".") or str(e).startswith(k + ":"))),
                    None)
        print(f"config: error: {in_file(e, path) if path else e}", file=sys.stderr)
        return 1
    for w in checks + site_warnings(site, doc, friction_doc):
        print(f"config: warning: {w}", file=sys.stderr)
    out = Path(args.out)
    try:
        write_node_json(out, doc)
    except OSError as e:
        print(f"config: error: cannot write {out}: {e.strerror or e}", file=sys.stderr)
        return 1
    print(describe(site, doc))
    print(f"wrote {out} (mode 0600, readable by its owner only: it holds node {site.node_id}'s key)")
    return 0
