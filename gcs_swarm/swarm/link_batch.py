"""``LinkState.receive_batch``: many datagrams of one peer at once, for a
link that reads a network's shared endpoint (``runtime.links.Link`` reads
up to ``READ_AHEAD`` datagrams at a time). While nothing of them would go
to a vehicle's protocol (flying vehicles' reports their rows take, their
unchanged HEARTBEATs and status messages), the frames are read in one pass
(``raw_frames.frame_batch``), the reports written column-wise
(``TelemetryTable.write_many``) and the counters moved once: the state
``LinkState.receive`` of each datagram in turn leaves
(tests/swarm/test_receive_batch.py), at a fraction of its cost. No I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from typing import TYPE_CHECKING, Any

from gcs_swarm.mavlink.raw_frames import FrameBatch, frame_batch

if TYPE_CHECKING:
    from gcs_swarm.mavlink.codec import Codec
    from gcs_swarm.mavlink.telemetry_table import TelemetryTable
    from gcs_swarm.swarm.link_state import LinkStats

__all__: list[str] = []

Peer = Hashable


class _LinkBatch:
    """``LinkState``'s ``receive_batch``, over the state it declares (the
    link state's, made in its ``__init__``)."""

    base: int
    stats: LinkStats
    rx_time_s: float
    positions_written: int
    _table: TelemetryTable | None
    _codecs: dict[Any, Codec]
    _rows: dict[int, int]
    _routes: dict[int, Any]
    _heard: dict[int, float]
    _on_frame: Callable[[bytes, Any], None] | None

    def receive_batch(self, grams: Sequence[bytes], peer: Peer, now: float) -> int:
        """``receive`` of the first datagrams of ``grams`` (from ``peer``,
        arrived by ``now``) in turn, at once, as far as nothing of them would
        come out as a message: every frame a flying vehicle's report its row
        takes (``TelemetryTable.write_many``) or its unchanged HEARTBEAT or
        status message (``TelemetryTable.recognised``), each vehicle one this
        link serves, bound to ``peer``, every frame whole and unsigned
        (``raw_frames.frame_batch``), in runs of datagrams with one report
        per vehicle (a vehicle's next report starts the next run).
        The same table, counters, ``on_frame`` and ``on_inbound`` calls (in
        the frames' order) as ``receive`` of each; ``positions_written`` the
        reports. Returns how many datagrams were taken (the caller calls
        ``receive`` for the rest). For a link that reads many vehicles'
        datagrams at a time from one peer (a network's shared endpoint);
        its array work costs about what 30 frames one by one do
        (``runtime.links.BATCH_BYTES``)."""
        self.positions_written = 0
        table, codec = self._table, self._codecs.get(peer)
        if table is None or codec is None or codec.signing_key is not None:
            return 0
        if not table.any_attached:
            # Nobody flies yet (start-up): every report goes to its protocol,
            # so the frames are not parsed twice (measured at 1,500 vehicles:
            # 15 % of the start-up's loop in batches declined, 2026-12-06).
            return 0
        batch = frame_batch(grams)
        if batch is None:
            return 0
        sysids = batch.head[:, 5].tolist()
        # Runs of whole datagrams in which no vehicle reports twice.
        lpn, cuts = batch.lpn, batch.cuts
        taken = lo = at = 0  # datagrams taken, their frames, lpn entries before lo
        while taken < len(cuts):
            seen: set[int] = set()
            end, hi = at, taken
            while hi < len(cuts):
                stop = end
                while stop < len(lpn) and lpn[stop] < cuts[hi]:
                    stop += 1
                run = {sysids[j] for j in lpn[end:stop]}
                if len(run) < stop - end or not seen.isdisjoint(run):
                    break
                seen |= run
                end, hi = stop, hi + 1
            if hi == taken or not self._take(batch, sysids, lo, cuts[hi - 1], at, end, peer, now):
                break
            taken, lo, at = hi, cuts[hi - 1], end
        return taken

    def _take(self, batch: FrameBatch, sysids: list[int], lo: int, hi: int, a: int, b: int,
              peer: Peer, now: float) -> bool:  # fmt: skip
        """``receive_batch``'s frames ``lo`` to ``hi - 1`` (its reports ``a``
        to ``b - 1``), all or none."""
        table, codec = self._table, self._codecs[peer]
        assert table is not None
        if table.attention:  # serviced after each datagram by receive's caller: not here
            return False
        rows, routes = self._rows, self._routes
        ids = sysids[lo:hi]
        for sysid in set(ids):
            if sysid not in rows or routes.get(sysid) != peer:
                return False  # not served, or not (yet) bound to this peer: receive's rules
        said = []
        for j, raw in batch.others:
            if lo <= j < hi:
                k = rows[raw[0]]
                times = table.recognised(k, raw[1], raw[3][7], raw[4])
                if times is None:
                    return False
                said.append((k, times))
        lpn = batch.lpn[a:b]
        ks = [rows[sysids[j]] for j in lpn]
        compids = batch.head[lo:hi, 6].tolist()
        quiet = {k for k, _ in said}
        if not table.write_many(ks, [compids[j - lo] for j in lpn], batch.payload[a:b],
                                now, now, quiet):  # fmt: skip
            return False
        for k, times in said:
            times[k] = now
        heard = self._heard
        for sysid in ids:
            heard[sysid] = now
        codec.stats.received += hi - lo
        self.stats.received += hi - lo
        self.stats.frames_batched += hi - lo
        self.rx_time_s = now
        self.positions_written += len(ks)
        blob = batch.blob
        if self._on_frame is not None:
            on_frame = self._on_frame
            for i, e in zip(batch.starts[lo:hi], batch.ends[lo:hi], strict=True):
                on_frame(blob[i:e], "in")
        if table.on_inbound is not None:
            inbound, base = table.on_inbound, self.base
            head = batch.head[lo:hi]
            for sysid, compid, seq, msgid in zip(ids, compids, head[:, 4].tolist(),
                                                 head[:, 7].tolist(), strict=True):  # fmt: skip
                inbound(sysid + base, compid, seq, msgid)
        return True
