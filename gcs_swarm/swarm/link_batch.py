"""``LinkState.receive_batch``: many datagrams of one peer at once, for a
link that reads a network's shared endpoint (``runtime.links.Link`` reads
up to ``READ_AHEAD`` datagrams at a time). While nothing of them would go
to a vehicle's protocol (flying vehicles' reports their rows take, their
unchanged HEARTBEATs and status messages), the frames are read in one pass
(``raw_frames.frame_batch``), the reports written column-wise
(``TelemetryTable.write_many``) and the counters moved once: the state
``LinkState.receive`` of each datagram in turn leaves
(tests/swarm/test_receive_batch.py), at a fraction of its cost.
``receive_batches`` goes on past a datagram the batch declines (a vehicle
of the network that is not flying: one that left, a reserve): that one
goes alone to the caller's ``receive``, and the batch takes what follows
from the same parse. No I/O.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from collections.abc import Callable, Hashable, Sequence
from typing import TYPE_CHECKING, Any

from gcs_swarm.mavlink.raw_frames import FrameBatch, frame_batch

if TYPE_CHECKING:
    from gcs_swarm.mavlink.codec import Codec
    from gcs_swarm.mavlink.telemetry_table import TelemetryTable
    from gcs_swarm.swarm.link_state import LinkStats

__all__ = ["SPLITS"]

Peer = Hashable

SPLITS = 8
"""Datagrams a read's batch declines that ``receive_batches`` hands on
alone and goes on past, at most; after that (or a retry that took
nothing) the rest goes one by one. One vehicle of a network that is not
flying puts its reports in one datagram of each period's; eight bound a
read's work when the station has fallen behind (``READ_AHEAD`` datagrams,
several periods) and many vehicles are not flying."""


class _LinkBatch:
    """``LinkState``'s ``receive_batches`` and ``receive_batch``, over the
    state it declares (the link state's, made in its ``__init__``)."""

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

    def receive_batches(
        self, grams: Sequence[bytes], peer: Peer, now: float,
        alone: Callable[[bytes], None], took: Callable[[], None],
    ) -> int:  # fmt: skip
        """``receive_batch`` of ``grams``, and past each datagram it
        declines: that one goes to ``alone`` (the caller's ``receive`` of it,
        its messages handed on), then the batch takes what follows, from
        the same parse while it lasts, at most ``SPLITS`` times, while each
        retry takes something. ``took()`` after each run of datagrams taken
        (the caller's ``on_telemetry``). Returns how many datagrams of
        ``grams`` were handled (the caller receives the rest). The state
        left is that of ``receive`` of each datagram in turn, as
        ``receive_batch``'s; but a datagram handed on alone is not read
        ahead (``Link``'s ``superseded``): a vehicle not flying gets each of
        its reports in it, not only its newest of the read."""
        base, done = 0, 0  # the first datagram parsed, the first not handled
        batch = self._parse(grams, peer)
        for split in range(SPLITS + 1):
            if batch is None or (split and not self._batchable(peer)):  # as alone left it
                break
            end = base + self.receive_batch(grams, peer, now, parsed=batch, start=done - base)
            if end > done:
                took()
            elif split:  # the retry after a datagram alone took nothing
                break
            done = end
            if done == len(grams) or split == SPLITS:
                break
            alone(grams[done])
            done += 1
            if done - base >= len(batch.cuts):  # past the parse (frame_batch stopped there)
                base = done
                batch = self._parse(grams[done:], peer) if done < len(grams) else None
        return done

    def _parse(self, grams: Sequence[bytes], peer: Peer) -> FrameBatch | None:
        """``frame_batch`` of ``grams``, or None when no batch can be taken
        from ``peer`` now (``_batchable``)."""
        return frame_batch(grams) if self._batchable(peer) else None

    def _batchable(self, peer: Peer) -> bool:
        """Whether a batch can be taken from ``peer`` now: a table, the
        peer's codec, unsigned, and a row taking reports."""
        table, codec = self._table, self._codecs.get(peer)
        if table is None or codec is None or codec.signing_key is not None:
            return False
        # Nobody flies yet (start-up): every report goes to its protocol, so
        # the frames are not parsed twice (measured at 1,500 vehicles: 15 %
        # of the start-up's loop in batches declined, 2026-12-06).
        return table.any_attached

    def receive_batch(self, grams: Sequence[bytes], peer: Peer, now: float, *,
                      parsed: FrameBatch | None = None, start: int = 0) -> int:  # fmt: skip
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
        (``runtime.links.BATCH_BYTES``). With ``parsed`` (``_parse`` of
        ``grams``, which are then not read again) from datagram ``start``
        on, those before it handled; returns the first datagram not taken."""
        self.positions_written = 0
        batch = self._parse(grams, peer) if parsed is None else parsed
        if batch is None or start >= len(batch.cuts):
            return start
        sysids = batch.sysids
        # Runs of whole datagrams in which no vehicle reports twice.
        lpn, cuts = batch.lpn, batch.cuts
        taken = start  # datagrams taken; their frames (lo) and the lpn entries before lo (at)
        lo = cuts[start - 1] if start else 0
        at = bisect_left(lpn, lo)
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
            if hi == taken:
                break
            bad = self._not_flying(sysids, lo, cuts[hi - 1], peer)
            if bad is not None:
                # A frame of a vehicle not flying (or not this link's, or
                # not bound to ``peer``: receive's rules) in the run: the
                # datagrams before the one holding it may still go
                # (receive_batches hands that one on alone).
                cut = bisect_right(cuts, bad)
                if cut > taken:
                    end = bisect_left(lpn, cuts[cut - 1])
                    if self._take(batch, sysids, lo, cuts[cut - 1], at, end, peer, now):
                        taken = cut
                break
            if not self._take(batch, sysids, lo, cuts[hi - 1], at, end, peer, now):
                break
            taken, lo, at = hi, cuts[hi - 1], end
        return taken

    def _not_flying(self, sysids: list[int], lo: int, hi: int, peer: Peer) -> int | None:
        """The first frame of ``lo`` to ``hi - 1`` of a vehicle whose row
        takes no reports (not flying), that this link does not serve, or
        that is not bound to ``peer``; None if there is none."""
        table = self._table
        assert table is not None
        rows, routes, owners = self._rows, self._routes, table.owners
        bad = set()
        for sysid in set(sysids[lo:hi]):
            k = rows.get(sysid)
            if k is None or routes.get(sysid) != peer or owners[k] is None:
                bad.add(sysid)
        if not bad:
            return None
        return next(j for j in range(lo, hi) if sysids[j] in bad)

    def _take(self, batch: FrameBatch, sysids: list[int], lo: int, hi: int, a: int, b: int,
              peer: Peer, now: float) -> bool:  # fmt: skip
        """``receive_batch``'s frames ``lo`` to ``hi - 1`` (its reports ``a``
        to ``b - 1``), all or none; each of a flying vehicle this link
        serves, bound to ``peer`` (``_not_flying``)."""
        table, codec = self._table, self._codecs[peer]
        assert table is not None
        if table.attention:  # serviced after each datagram by receive's caller: not here
            return False
        rows = self._rows
        ids = sysids[lo:hi]
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
