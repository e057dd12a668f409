"""Injected corruption (``--corrupt-rx P``): a noisy wire on the printer's receive side.

Each line the host sends has, with probability P, one random bit of one random byte flipped
before the printer reads it: any bit of any byte, the line's end included, as on a real wire, and
Marlin's line-number and checksum checks catch what they catch. The transcript shows what the
printer received, each flip announced by a ``*`` event naming the byte (in the ``>`` chunk that
follows) and the bit.
"""

from __future__ import annotations

import random
from collections import OrderedDict


class RxCorruptor:
    """Flips one random bit of one random byte in a fraction of the host's lines (``--corrupt-rx``).

    Lines are cut at every CR or LF (the end of line belongs to its line and may be hit too);
    bytes after the last one wait for the rest of their line, which changes nothing the printer
    does, as Marlin acts on a line only at its end. Whether and where a line is hit is drawn by
    ``random.Random`` seeded with the seed, the line's bytes and how many times the same bytes
    came before (since ``reset()``, a host's arrival): a resent line gets a fresh draw, and a
    host that sends the same lines gets the same flips every run, however its writes are cut up,
    and whatever it sends in between (an extra line a host's race sends does not move the flips
    onto other lines). Python keeps string seeding and ``random()``'s sequence across versions.
    Repeats are counted for the last REPEATS_KEPT distinct lines: a resend asks for a recent one.

    No flip makes the printer raise or hang, but some stop a host as they would on a real
    printer. A flipped end of line leaves its line open until the host sends more, and a line
    number flipped to the last one is dropped silently as a duplicate: a host that sends the
    next line only after an ``ok`` and has no timeout (Printrun's printcore) waits forever. An
    unnumbered ``M110`` or ``M113`` can become ``M112``, which kills the board; a numbered line
    cannot (Marlin looks for emergency commands only at the start of a line).
    """

    REPEATS_KEPT = 1024

    def __init__(self, probability: float, seed: int = 0):
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"the rx corruption probability (--corrupt-rx) must be within 0..1, "
                             f"not {probability!r}")
        self.probability = probability
        self.seed = seed
        self.reset()

    def __repr__(self) -> str:
        return f"RxCorruptor(probability {self.probability:g}, seed {self.seed})"

    def reset(self) -> None:
        """Forget the lines seen and a partial line (a new host, a board reset)."""
        self._seen: OrderedDict[bytes, int] = OrderedDict()
        self._partial = bytearray()

    def feed(self, data: bytes) -> tuple[bytes, list[tuple[int, int]]]:
        """The complete lines in ``data`` (after what waited), some corrupted, and the flips
        made as (index of the byte in the returned bytes, bit 0..7)."""
        self._partial += data
        end = max(self._partial.rfind(b"\n"), self._partial.rfind(b"\r")) + 1
        lines = self._partial[:end]
        del self._partial[:end]
        flips = []
        start = 0
        for i in range(end):
            if lines[i] in b"\r\n":
                flip = self._draw(bytes(lines[start:i + 1]))
                if flip is not None:
                    index, bit = start + flip[0], flip[1]
                    lines[index] ^= 1 << bit
                    flips.append((index, bit))
                start = i + 1
        return bytes(lines), flips

    def _draw(self, line: bytes) -> tuple[int, int] | None:
        """The (byte index, bit) to flip in this occurrence of ``line``, or None."""
        repeat = self._seen.pop(line, -1) + 1
        self._seen[line] = repeat
        if len(self._seen) > self.REPEATS_KEPT:
            self._seen.popitem(last=False)
        rng = random.Random(f"{self.seed}:{repeat}:{line.hex()}")
        if rng.random() >= self.probability:
            return None
        return int(rng.random() * len(line)), int(rng.random() * 8)
