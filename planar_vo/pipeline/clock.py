"""`FrameClock`: judges each frame's stamp against the stream's time base.

Real streams have clock hiccups: a single frame stamped far in the future (one bad clock
sample), a bag played in a loop or a restarted clock (stamps jump back), a driver restart (a
long real gap). None of them may stop the odometry for good:

- a frame whose stamp lies more than ``max_gap`` seconds ahead is that frame's problem only: it
  is refused (`StampCheck.JUMP_AHEAD`) and the time base is kept, unless the next frame confirms
  the new time (it follows it within ``max_gap``): then the stream really moved on
  (`StampCheck.NEW_TIME_BASE`) and tracking restarts there;
- likewise a stamp more than ``max_jump_back`` seconds behind the last one is refused
  (`StampCheck.FAR_BEHIND`; a user test: one frame stamped 0 in a drive reset the rest of it
  to the origin) unless the next frame confirms the older time (it follows it within
  ``max_gap`` and is still that far behind): a looped bag or a restarted clock
  (`StampCheck.JUMP_BACK`), and tracking is reset there; a smaller step back is a frame out
  of order;
- a frame stamped ahead of its time by less than ``max_gap`` (or up to `GAP_WATCH` in a row:
  a clock stepped forward and back) opens what looks like a gap of lost frames, and the
  frames after it are older: the first of them is refused (`StampCheck.INSIDE_GAP`), and a
  later one may confirm that the frames since the gap were stamped ahead
  (`StampCheck.REWOUND`, a proposal): if the caller accepts it
  (`FrameClock.rewind`), the time goes on from the frames' own stamps (a user test: a frame
  stamped 0.8 s ahead refused the 7 frames after it, one 3 s ahead reset the pose to the
  origin as a looped bag); else they are frames delivered late into a real gap, refused.

Stamps are float seconds. A float holds about 0.24 us at 1.7e9 s, so two stamps 1 ns apart may
be the same float: where the source has integer nanoseconds (ROS header stamps, bag times), a
`Stamp` keeps them, and two `Stamp` s are compared exactly (a frame 1 ns later is not a
duplicate).
"""

from __future__ import annotations

import collections
import enum
import statistics
from dataclasses import dataclass

__all__ = ['FrameClock', 'Gap', 'GapCounter', 'RateChange', 'Stamp', 'StampCheck',
           'format_stamp', 'seconds_between', 'shift_stamp']


class Stamp(float):
    """Seconds (a float, usable wherever one is) that keep the integer nanoseconds they were
    made from, ``Stamp(stamp_ns)``; `FrameClock` compares two of them exactly."""

    __slots__ = ('ns',)

    def __new__(cls, ns: int) -> Stamp:
        stamp = super().__new__(cls, int(ns) / 1_000_000_000)     # int / int: correctly rounded
        stamp.ns = int(ns)
        return stamp

    def __reduce__(self):
        return Stamp, (self.ns,)        # float's would pass the seconds as nanoseconds


def format_stamp(stamp: float) -> str:
    """Seconds as text: a `Stamp`'s exact nanoseconds (``1700000000.415494000``, as the header
    had them), a plain float's to the microsecond (at 1.7e9 s a float holds about 0.2 us: more
    digits would be noise)."""
    if isinstance(stamp, Stamp):
        # (a user test: -4.61 s printed as -5.389627000)
        sec, nsec = divmod(abs(stamp.ns), 1_000_000_000)
        return f"{'-' if stamp.ns < 0 else ''}{sec}.{nsec:09d}"
    return f'{stamp:.6f}'


def seconds_between(later: float, earlier: float) -> float:
    """``later - earlier`` in seconds, exact to the nanosecond between two `Stamp` s (plain
    floats near 1.7e9 s hold about 0.2 us: two stamps 1 ns apart subtract to 0)."""
    if isinstance(later, Stamp) and isinstance(earlier, Stamp):
        return (later.ns - earlier.ns) / 1_000_000_000
    return later - earlier


class StampCheck(str, enum.Enum):
    """The verdict on one frame's stamp."""

    OK = 'ok'
    DUPLICATE = 'duplicate'              # the same stamp as the last accepted frame
    TOO_CLOSE = 'too_close'              # far sooner after it than the frames' usual interval
    OUT_OF_ORDER = 'out_of_order'        # slightly older than the last accepted frame
    JUMP_AHEAD = 'jump_ahead'            # far in the future: refused, time base kept
    NEW_TIME_BASE = 'new_time_base'      # the second frame after a forward jump: accepted
    FAR_BEHIND = 'far_behind'            # far in the past: refused, time base kept
    JUMP_BACK = 'jump_back'              # the second frame far in the past: a new time base
    INSIDE_GAP = 'inside_gap'            # older than the last accepted frame, inside the gap
    #                                      that frame opened: refused
    REWOUND = 'rewound'                  # a later one inside it: the last accepted frame may
    #                                      have been stamped ahead of its time (`rewind` takes
    #                                      this frame; else it is refused, as INSIDE_GAP)


# An interval this many times the usual one is a gap (frames lost, or a frame stamped ahead).
GAP_FACTOR = 1.8
# Frames accepted after a gap during which frames inside it may still show that they were
# stamped ahead (a clock stepped forward for a few frames; a review: at 3, four frames ahead
# were not found, 0.13 s at 30 Hz).
GAP_WATCH = 10


def shift_stamp(stamp: float, seconds: float) -> float:
    """``stamp`` moved back by ``seconds`` (a `Stamp` stays one, to the nanosecond)."""
    if isinstance(stamp, Stamp):
        return Stamp(stamp.ns - round(seconds * 1_000_000_000))
    return stamp - seconds


class FrameClock:
    """The last accepted stamp and the rules above.

    A frame stamped less than `TOO_CLOSE_SHARE` of the usual interval (the median of the last
    `INTERVALS` accepted ones, once there are 3) and less than `TOO_CLOSE_S` after the last one
    is a duplicated or mis-stamped frame: the motion between two images divided by a 1 ns
    interval published a speed of 1e9 m/s (a user test). The absolute bound lets a camera
    switch to a higher frame rate (up to 200 Hz) without losing frames while the usual interval
    catches up.

    Args:
        max_gap: the longest plausible interval between consecutive frames (seconds).
        max_jump_back: a step back longer than this (seconds) is refused unless the next
            frame confirms it (then a new time base); a shorter one is a frame out of order.
    """

    TOO_CLOSE_SHARE = 0.25
    TOO_CLOSE_S = 0.005
    INTERVALS = 9

    def __init__(self, max_gap: float, max_jump_back: float) -> None:
        self.max_gap = float(max_gap)
        self.max_jump_back = float(max_jump_back)
        self.last: float | None = None
        # Seconds from the last accepted stamp to the first of the two that confirmed the last
        # new time base (negative: back), for messages.
        self.jump = 0.0
        self._ahead: float | None = None
        self._behind: float | None = None
        self._intervals: collections.deque[float] = collections.deque(maxlen=self.INTERVALS)
        # The gaps among the last `GAP_WATCH` accepted frames (and the first two intervals,
        # which may be ones): [stamp before, stamp after, frames accepted since (the one after
        # included), whether it is one of the first two intervals]; the first frame refused
        # inside one.
        self._gaps: list[list] = []
        # The last `StampCheck.INSIDE_GAP` was inside one of the first two intervals (watched
        # as gaps before the usual interval is known), not inside a gap seen as one.
        self.inside_start = False
        self._inside: tuple[float, float] | None = None     # (first, latest)
        # After `StampCheck.REWOUND`: the stamp of the first frame after the gap and the
        # seconds by which it and the frames after it were ahead (the gap's slots shared
        # evenly by them and the first frame inside it), and the frame that would go on.
        self.mis_stamped: tuple[float, float] | None = None
        self._proposed: tuple[float, float] | None = None   # (that frame, the inside before)

    def reset(self) -> None:
        """Forget the time base (the next stamp is accepted as is)."""
        self.last = None
        self._ahead = self._behind = None
        self._inside = self._proposed = self.mis_stamped = None
        self._gaps.clear()
        self._intervals.clear()

    @property
    def usual_interval(self) -> float | None:
        """The median of the recent accepted intervals (seconds), once there are 3."""
        if len(self._intervals) < 3:
            return None
        return statistics.median(self._intervals)

    def check(self, stamp: float) -> StampCheck:
        """Judge ``stamp`` (seconds, or a `Stamp`) and, when it is accepted, make it the last
        stamp."""
        last = self.last
        if last is None:
            self.last, self._ahead, self._behind = stamp, None, None
            return StampCheck.OK
        step = seconds_between(stamp, last)
        if step == 0.0:
            return StampCheck.DUPLICATE
        # Older than the last accepted frame and after the start of a recent gap: inside the
        # time the frames since that gap should have filled (not only inside the gap: a user
        # test, two frames 0.3 s ahead left one frame inside it, three none).
        gap = next((g for g in reversed(self._gaps) if seconds_between(stamp, g[0]) > 0.0),
                   None) if step < 0.0 else None
        if gap is not None:
            # (Before the jump-back rules: a frame stamped 3 s ahead is not a looped bag.) The
            # first frame inside times the slots of the frames since the gap (a refused
            # proposal does not: a review, the rewind shrank with each); a later one proposes.
            first_inside, latest = self._inside if self._inside is not None else (None, None)
            self._ahead = self._behind = None
            if first_inside is not None and seconds_between(stamp, latest) > 0.0 \
                    and seconds_between(first_inside, gap[0]) > 0.0:
                likely = seconds_between(first_inside, gap[0]) / (gap[2] + 1)
                self.mis_stamped = (gap[1], seconds_between(gap[1], gap[0]) - likely)
                self._inside, self._proposed = (first_inside, stamp), (stamp, latest)
                return StampCheck.REWOUND
            self._inside = (stamp, stamp)
            self.inside_start = gap[3]
            return StampCheck.INSIDE_GAP
        if step < 0.0:
            if -step <= self.max_jump_back:
                return StampCheck.OUT_OF_ORDER
            if self._follows(stamp, self._behind):
                self.jump = seconds_between(self._behind, last)
                self._new_base(stamp)
                return StampCheck.JUMP_BACK
            # One pending stamp at a time (a review: a far-behind glitch, a far-ahead one and
            # a frame after the first confirmed a jump back).
            self._behind, self._ahead = stamp, None
            return StampCheck.FAR_BEHIND
        if step > self.max_gap:
            if self._follows(stamp, self._ahead):
                self.jump = seconds_between(self._ahead, last)
                self._new_base(stamp)
                return StampCheck.NEW_TIME_BASE
            self._ahead, self._behind = stamp, None
            return StampCheck.JUMP_AHEAD
        usual = self.usual_interval
        if usual is not None and step < min(self.TOO_CLOSE_SHARE * usual, self.TOO_CLOSE_S):
            return StampCheck.TOO_CLOSE
        # The gaps watched: each a few frames long (a review: a second glitch right after a
        # first replaced it, and neither was found); the first two intervals too (a frame 1 or
        # 2 stamped ahead left the pose 7 m behind for good).
        for g in self._gaps:
            g[2] += 1
        self._gaps = [g for g in self._gaps if g[2] <= GAP_WATCH]
        if len(self._intervals) < 2 or step > GAP_FACTOR * statistics.median(self._intervals):
            self._gaps.append([last, stamp, 1, len(self._intervals) < 2])
        self._inside = self._proposed = None
        self.last, self._ahead, self._behind = stamp, None, None
        self._intervals.append(step)
        return StampCheck.OK

    def rewind(self) -> None:
        """Accept the `StampCheck.REWOUND` just returned: the frames since the last gap were
        stamped ahead of their time (`mis_stamped`), and the time goes on from the frame that
        proposed it."""
        proposed, self._proposed = self._proposed, None
        if proposed is None:
            raise RuntimeError('FrameClock.rewind: no StampCheck.REWOUND to accept')
        # The proposing frame may be stamped ahead too (a review: it became the time base and
        # the frames after it were refused): the interval from the frame inside before it is
        # watched as a gap.
        stamp, latest = proposed
        self.jump = seconds_between(stamp, self.last)
        self.last, self._ahead, self._behind = stamp, None, None
        self._inside = None
        self._gaps = [[latest, stamp, 1, False]]

    def _follows(self, stamp: float, refused: float | None) -> bool:
        """``stamp`` confirms the time of the frame refused before it: it comes after it,
        within ``max_gap``."""
        return refused is not None and 0.0 < seconds_between(stamp, refused) <= self.max_gap

    def _new_base(self, stamp: float) -> None:
        self.last, self._ahead, self._behind = stamp, None, None
        self._inside = self._proposed = None
        self._gaps.clear()
        self._intervals.clear()


@dataclass(frozen=True)
class RateChange:
    """The last `GapCounter.RATE_CHANGE_GAPS` gaps were the camera's new frame rate (taken off
    the counts)."""

    before_hz: float
    after_hz: float


@dataclass(frozen=True)
class Gap:
    """Frames lost before a stamp: the interval (ns), about how many frames are missing, the
    nominal period (ns) it was judged against, the rate change it completed (if any: then
    it and the gaps before it are off the counts), and whether the frames were lost while the
    receiver was busy (``behind``: `GapCounter.note`)."""

    interval_ns: int
    missing: int
    period_ns: float
    rate_change: RateChange | None = None
    behind: bool = False


class GapCounter:
    """Frames lost on the way: intervals far above the usual one, counted as ``gaps`` and
    ``missing`` frames (the node and replay share it).

    The stamps are judged by the pipeline's rules (`FrameClock`, the same limits): a duplicate,
    a frame out of order or a single stamp far ahead or behind (a clock glitch) leave the time
    base alone, and a confirmed jump back (a looped bag) or ahead starts a new one: none of
    them is a gap of lost frames. A frame refused as far ahead or behind came in the interval
    it falls in (its stamp is wrong, not the frame lost): it takes one of the interval's slots
    off the missing count (a user test: a frame stamped 1000 s ahead in place of the next one
    counted a frame missing besides its `time_jump_ahead`). An interval is judged from the
    second one on (a user test: frames lost right after the start went uncounted) against the
    median of the last `PERIOD_WINDOW` ones; `RATE_CHANGE_GAPS` gaps in a row of about one
    length are the camera's new frame rate (a driver reconfigured, auto-exposure at dusk, a
    throttled topic), not lost frames: the nominal period becomes theirs and they are taken
    off the counts. A frame refused inside the last gap (`StampCheck.INSIDE_GAP`: delivered out
    of order, or the frame that opened the gap was stamped ahead) fills one of its slots (a user
    test: a frame out of order counted as missing too); a second one after it in order
    (`StampCheck.REWOUND`: a mis-stamped frame opened the gap, or the frames came late) fills
    one, the frames since the gap theirs, and every later frame stamped inside it one.

    A gap that came while the receiver was busy (``note(..., busy=True)``: the frame was
    waiting when the last one was done, so the frames between were dropped from its queue) is
    counted in ``behind`` too, and never taken for a new frame rate (a user test: a node taking
    22 ms per frame of a 60 Hz camera lost 83 of 300 frames, called the camera's rate 30 Hz
    and counted 36 missing).
    """

    GAP_FACTOR = GAP_FACTOR     # an interval this many times the nominal period is a gap
    PERIOD_WINDOW = 20
    RATE_CHANGE_GAPS = 3
    RATE_CHANGE_SPREAD = 0.2    # ... gaps in a row within this share of their median

    def __init__(self, max_gap: float, max_jump_back: float) -> None:
        self._clock = FrameClock(max_gap, max_jump_back)
        self._last_ns: int | None = None
        self._intervals: collections.deque[int] = collections.deque(maxlen=self.PERIOD_WINDOW)
        # [interval, missing] of the last gaps in a row (a late frame fills one of the last's)
        self._run: collections.deque[list[int]] = collections.deque(maxlen=self.RATE_CHANGE_GAPS)
        self._glitched = 0      # frames refused as far ahead or behind since the last one
        self._open = 0          # frames the last gap (of the last few frames) still counts
        self._open_age = 0      # frames accepted since that gap
        self._open_behind = False   # ... it was the receiver's (`note`'s ``busy``)
        self._open_span: tuple[int, int] | None = None     # the stamps around that gap
        self._early: list[int] = []     # stamps of frames that came before frames stamped earlier
        self._after_gap: list[int] = []     # stamps accepted since the last gap (a few)
        self._recent: collections.deque[int] = collections.deque(maxlen=self.PERIOD_WINDOW)
        self.gaps = 0
        self.missing = 0
        self.behind = 0         # of the missing frames, those lost while the receiver was busy

    @property
    def period_ns(self) -> float | None:
        """The nominal frame interval (ns): the median of the recent intervals, or None
        before two."""
        return statistics.median(self._intervals) if len(self._intervals) >= 2 else None

    def refused(self) -> None:
        """A frame came whose stamp is no time at all (replay: not a ROS time): like one
        stamped far ahead or behind, it fills a slot of the interval it came in."""
        self._glitched += 1

    def note(self, stamp_ns: int, busy: bool = False) -> Gap | None:
        """Judge one frame's stamp (integer ns): the gap before it, or None. ``busy``: the
        frame was waiting while the receiver processed the one before (the frames of a gap
        before it were dropped from the receiver's queue, not by the camera)."""
        check = self._clock.check(Stamp(stamp_ns))
        if check in (StampCheck.JUMP_AHEAD, StampCheck.FAR_BEHIND, StampCheck.DUPLICATE,
                     StampCheck.TOO_CLOSE):
            # A frame that came with a wrong stamp fills a slot of the interval it came in (a
            # user test: a duplicated stamp in place of the next frame's counted one missing).
            self._glitched += 1
            return None
        if check is StampCheck.REWOUND:
            # Frames came inside the last gap in order: the frames since it were stamped ahead
            # of their time, or these came late. The stamps go on from here; this frame and
            # the ones since the gap fill slots of it, and so does every later frame stamped
            # inside it (a user test: late frames after a real gap took the whole gap off the
            # counts, the frames really lost with it). If these came late, the frames since
            # the gap lie outside it: their own slots are filled when the stream gets there.
            self._clock.rewind()
            self._fill(1 + len(self._after_gap))
            self._early.extend(self._after_gap)
            self._glitched, self._last_ns = 0, stamp_ns
            self._after_gap = [stamp_ns]
            return None
        if check is StampCheck.INSIDE_GAP and self._open > 0:
            self._fill(1)                   # a late frame fills one slot of the gap
            return None
        if check in (StampCheck.INSIDE_GAP, StampCheck.OUT_OF_ORDER):
            # Stamped before the previous frame with no gap open here to fill (that frame's
            # slot is taken): a new stamp is a wrong one, and the frame fills a slot of the
            # interval it came in (a user test: a frame stamped 56 ms early was counted out of
            # order and its slot missing too); the stamp of a frame already seen is that frame
            # sent again, which fills none.
            if stamp_ns not in self._recent:
                self._glitched += 1
            return None
        last, self._last_ns = self._last_ns, stamp_ns
        self._recent.append(stamp_ns)
        glitched, self._glitched = self._glitched, 0
        early = sum(1 for t in self._early if last is not None and last < t <= stamp_ns)
        self._early = [t for t in self._early if t > stamp_ns]
        inside = (self._open > 0 and self._open_span is not None
                  and self._open_span[0] < stamp_ns < self._open_span[1])
        if inside:
            self._fill(1)                   # stamped inside the gap it reopened: a slot filled
        self._open_age += 1
        if self._open_age > GAP_WATCH and not inside:
            self._open = 0
        if len(self._after_gap) <= GAP_WATCH:
            self._after_gap.append(stamp_ns)
        if check in (StampCheck.JUMP_BACK, StampCheck.NEW_TIME_BASE) or last is None:
            self._intervals.clear()
            self._run.clear()
            self._after_gap.clear()
            self._early.clear()
            self._open = 0
            return None
        dt = stamp_ns - last
        if len(self._intervals) >= 2:
            period = statistics.median(self._intervals)
            if dt > self.GAP_FACTOR * period:
                self._after_gap = [stamp_ns]
                missing = max(1, round(dt / period) - 1) - glitched - early
                if missing < 1:
                    return None     # the refused frames filled it: no gap, no new period
                self.gaps += 1
                self.missing += missing
                if busy:
                    self.behind += missing
                    self._run.clear()       # (the receiver's pace, not the camera's rate)
                    change = None
                else:
                    change = self._rate_change(dt, missing, period)
                self._open, self._open_age = (0 if change is not None else missing), 1
                self._open_span, self._open_behind = (last, stamp_ns), busy
                return Gap(dt, missing, period, change, busy)
        self._run.clear()
        self._intervals.append(dt)
        return None

    def _fill(self, frames: int) -> None:
        """``frames`` frames came in the slots of the open gap (at most all of them)."""
        frames = min(frames, self._open)
        if frames <= 0:
            return
        self._open -= frames
        self.missing -= frames
        if self._open_behind:                   # (frames of the receiver's gap came late)
            self.behind = max(self.behind - frames, 0)
        self.behind = min(self.behind, self.missing)
        if self._run:
            self._run[-1][1] -= frames
        if self._open == 0:                 # filled: no gap
            self.gaps -= 1
            if self._run:
                self._run.pop()

    def _rate_change(self, dt: int, missing: int, period: float) -> RateChange | None:
        run = self._run
        run.append([dt, missing])
        if len(run) < self.RATE_CHANGE_GAPS:
            return None
        lengths = [g for g, _ in run]
        middle = statistics.median(lengths)
        if max(lengths) - min(lengths) > self.RATE_CHANGE_SPREAD * middle:
            run.popleft()
            return None
        self.gaps -= len(run)
        self.missing -= sum(m for _, m in run)
        self._intervals.clear()
        self._intervals.extend(lengths)
        run.clear()
        return RateChange(1e9 / period, 1e9 / middle)
