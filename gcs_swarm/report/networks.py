"""A summary of a mission with networks, told by (network, system id).

The station, the flight record and ``figures.summarize_record`` know each
vehicle by its key, ``network index * 256 + sysid``
(``gcs_swarm.mission.vehicle_key``), which is the system id itself in a
mission without networks: their summaries are left exactly as they were.
With ``networks:`` in the mission, ``label_summary`` rewrites every vehicle
reference of a summary to its label ``"network:sysid"`` (``"blue:7"``), gives
each vehicle entry its ``network`` and ``sysid``, each event its network,
and adds a ``networks`` block: per network its index, its telemetry log
and its vehicles' system ids.
"""

from __future__ import annotations

from typing import Any

from gcs_swarm.mission.model import DEFAULT_NETWORK, KEY_STRIDE, key_label

__all__ = ["label_summary"]

#: Overall fields holding one vehicle key, or a list of them.
_ONE = ("min_clearance_vehicle", "peak_accel_vehicle")
_MANY = ("vehicles_seen", "vehicles_flown", "vehicles_final", "min_separation_pair")
#: Station blocks keyed by str(key) (``runtime.run``'s extra figures).
_STATION_BY_KEY = ("telemetry_rate", "velocity_bias")


def label_summary(summary: dict[str, Any], networks: tuple[str, ...]) -> dict[str, Any]:
    """``summary`` with its vehicles told by ``network:sysid`` (module
    docstring); unchanged for a mission without networks. Works in place and
    returns it."""
    if networks == (DEFAULT_NETWORK,):
        return summary

    def lab(key: Any) -> Any:
        return key if key is None else key_label(int(key), networks)

    def where(key: int) -> dict[str, Any]:
        index, sysid = divmod(int(key), KEY_STRIDE)
        return {"network": networks[index] if index < len(networks) else None, "sysid": sysid}

    vehicles = summary.get("vehicles", {})
    relabelled: dict[str, Any] = {}
    for key, v in vehicles.items():
        v = {**where(int(key)), **v}
        if isinstance(v.get("final_distances_m"), dict):
            v["final_distances_m"] = {lab(k): d for k, d in v["final_distances_m"].items()}
        if v.get("min_separation_with") is not None:
            v["min_separation_with"] = lab(v["min_separation_with"])
        relabelled[lab(key)] = v
    summary["vehicles"] = relabelled
    overall = summary.get("overall", {})
    for name in _ONE:
        if name in overall:
            overall[name] = lab(overall[name])
    for name in _MANY:
        if overall.get(name) is not None:
            overall[name] = [lab(k) for k in overall[name]]
    for event in overall.get("events", ()):
        key = event["sysid"]
        event.update(where(key), vehicle=lab(key))
    station = summary.get("station", {})
    for name in _STATION_BY_KEY:
        if isinstance(station.get(name), dict):
            station[name] = {lab(k): x for k, x in station[name].items()}
    seen = [int(k) for k in vehicles]
    summary["networks"] = {
        name: {
            "index": j,
            "tlog": f"flight-{name}.tlog",
            "sysids": sorted(k % KEY_STRIDE for k in seen if k // KEY_STRIDE == j),
        }
        for j, name in enumerate(networks)
    }
    return summary
