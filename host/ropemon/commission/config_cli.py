"""`ropemon config SITE.toml [--out node.json]`: the node config for a site.

SITE.toml -> ropemon.commission.site (validated site, `physical` section with the pipe loss
tables, the friction fit and the optional hydraulic compliance fit) ->
ropemon.commission.nodejson.make_node_json (fixed-point `node` section with the node's id
and key, every integer proved within +-2**30, schema, CRC, SHA-256) -> node.json, written
with mode 0600 (it holds the key). A site file, friction or compliance fit that cannot be
used is refused with the field and the reason, exit 1.
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
    if cover is not None and cover["empty_reach"] >= cover["limit"]:
        out.append(
            f"deviation alarm: the seals may hold up to +-{cover['empty_s_N'] / 1e3:.1f} kN per rope with the cage "
            f"empty at the pithead ({cover['empty_rope_N'] / 1e3:.1f} kN a rope), so with no rope's seal seen "
            f"sliding the station's band reaches +-{cover['empty_reach']:.1%} of deviation there "
            f"({cover['rated_reach']:.1%} at the rated rope tension), beyond the {cover['limit']:.0%} limit: "
            "DEVIATION POSSIBLE will stand whenever the node has not seen the seals slide; check the ropes' "
            "balance by other means (docs/accuracy.md, \"What to distrust and what to do\")")
    if site.sensors.temperature is None:
        temps = site.oil.table_temps_C
        out.append(f"oil: no temperature input: losses are compensated at {site.oil.temp_assumed_C:g} C; "
                   f"the table covers {temps[0]:g}..{temps[-1]:g} C for a node with an input")
    return out


def deviation_cover(physical: dict[str, Any], empty_rope_n: float, rated_rope_n: float) -> dict[str, float] | None:
    """How far the station's band reaches when no rope's seal has been seen sliding, with the ropes
    equal at the empty cage's and at the rated rope tension (`ropemon.station.uncertainty`); None without
    friction lines."""
    from ropemon.station.uncertainty import BandParams, RopeInterval, deviation_bounds

    band = BandParams.from_physical(physical)
    if band is None:
        return None
    out: dict[str, float] = {"limit": float(physical.get("imbalance_frac", 0.1))}
    for name, t in (("empty", empty_rope_n), ("rated", rated_rope_n)):
        ivs = []
        for area in band.areas_m2:
            s, _fc, _floor = band.limits(t / area / 1000.0)
            ivs.append(RopeInterval(t, max(0.0, t - s), t + s, t, s, False))
        out[f"{name}_rope_N"] = t
        out[f"{name}_s_N"] = ivs[0].s
        out[f"{name}_reach"] = max(b.reach for b in deviation_bounds(ivs) if b is not None)
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
        f"config CRC 0x{doc['crc']:04x}, schema {doc['schema']}",
    ])


def add_arguments(p) -> None:
    p.add_argument("site", metavar="SITE.toml", help="site description (docs/commissioning.md)")
    p.add_argument("--out", default="node.json", help="node config to write (default: node.json)")
    p.add_argument("--friction", metavar="FRICTION.json",
                   help="friction fit to use instead of the site's [friction] file")
    p.add_argument("--compliance", metavar="COMPLIANCE.json",
                   help="hydraulic compliance fit to use instead of the site's [compliance] file")


def run(args) -> int:
    friction = None
    try:
        site = load_site(args.site)
    except SiteError as e:
        print(f"config: error: {in_file(e, args.site)}", file=sys.stderr)
        return 1
    fpath = Path(args.friction) if args.friction else site.friction_path
    try:
        friction_doc = None
        if fpath is not None:
            friction_doc = read_friction(fpath)
            friction = friction_doc
        compliance = read_compliance(args.compliance) if args.compliance else None
        doc = node_json_from_site(site, friction, compliance)
    except SiteError as e:  # a fault of the fit files is named with the file (of SITE.toml, with the field)
        fits = {"friction": fpath if friction is not None else None, "compliance": args.compliance}
        path = next((p for k, p in fits.items() if p and (str(e).startswith(k + ".") or str(e).startswith(k + ":"))),
                    None)
        print(f"config: error: {in_file(e, path) if path else e}", file=sys.stderr)
        return 1
    for w in site_warnings(site, doc, friction_doc):
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
