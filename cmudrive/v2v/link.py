"""The V2V link: each CAV pulls one partner's occupancy map per tick, through a link with the knobs of
the cooperative-perception literature (OpenCOOD's ``wild_setting``, HEAL's pose noise).

Per tick, every active CAV with a partner (:mod:`cmudrive.v2v.partner`) receives that partner's *own*
occupancy (never a merged one, so nothing echoes between CAVs) together with the partner's pose as the
partner measured it, warps it into its frame (:mod:`cmudrive.v2v.warp`) and ORs it with its own. The
link, all off by default (:class:`LinkConfig`):

- ``range_m``: a message between CAVs farther apart than this (centre to centre, at receive time) is
  lost (counted ``out_of_range``);
- ``latency_ticks``: the message received at tick t is the one the partner built at tick t - latency
  (its map and its pose then); before the partner has such a message, nothing is received;
- ``pose_noise_m`` / ``pose_noise_deg``: Gaussian noise (standard deviation per axis, and on yaw) on the
  partner's pose as received, as in OpenCOOD's ``loc_err`` and HEAL's ``pos_std`` / ``rot_std``, applied
  to the sender only, never to the ego;
- ``drop_rate``: probability that a sent message is lost.

Bytes: a message is a 16-byte header (sender, receiver, tick, a spare word; int32 each), the pose as three
float32 (12 bytes) and the occupancy bit-packed (C x H x W bits, rounded up to bytes): 12,316 bytes at the
default 4 x 192 x 128 grid. Every sent message counts, dropped ones too (they used the channel).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from cmudrive.sensors.occupancy import NUM_CLASSES, OccupancyConfig
from cmudrive.v2v.partner import NO_PARTNER, PartnerConfig, select_partners
from cmudrive.v2v.warp import warp_and_merge

HEADER_BYTES = 16
POSE_BYTES = 12


@dataclass(frozen=True)
class LinkConfig:
    range_m: float | None = None  # [m] None: no range limit
    latency_ticks: int = 0  # [ticks of 0.05 s]
    pose_noise_m: float = 0.0  # [m] sigma on the received x and y of the partner
    pose_noise_deg: float = 0.0  # [deg] sigma on the received yaw of the partner
    drop_rate: float = 0.0  # [-] probability that a message is lost

    def __post_init__(self) -> None:
        if self.range_m is not None and not self.range_m > 0.0:
            raise ValueError(f"link range_m must be positive (or None for no limit), got {self.range_m}")
        if self.latency_ticks < 0:
            raise ValueError(f"link latency_ticks must be >= 0, got {self.latency_ticks}")
        if not (self.pose_noise_m >= 0.0 and self.pose_noise_deg >= 0.0):
            raise ValueError("link pose noise must be >= 0")
        if not 0.0 <= self.drop_rate <= 1.0:
            raise ValueError(f"link drop_rate must be in [0, 1], got {self.drop_rate}")


def message_bytes(config: OccupancyConfig, num_classes: int = NUM_CLASSES) -> int:
    h, w = config.shape
    return HEADER_BYTES + POSE_BYTES + (num_classes * h * w + 7) // 8


@dataclass(frozen=True)
class Exchange:
    """One tick of V2V for the ``n`` active CAVs."""

    partner: np.ndarray  # (n,) CAV index of the partner chosen, -1 for none
    received: np.ndarray  # (n,) bool: the partner's map arrived and was merged
    merged: np.ndarray  # (n, C, H, W) bool: own OR warped partner map


@dataclass
class LinkStats:
    messages: int = 0  # sent (one per CAV with a partner per tick)
    received: int = 0
    dropped: int = 0  # lost to drop_rate
    out_of_range: int = 0  # lost to range_m
    not_yet: int = 0  # latency: the partner had no message that old yet
    bytes: int = 0  # of all sent messages
    cav_ticks: int = 0  # active CAVs summed over ticks: how many partner choices were made
    named: int = 0  # of those, the agent named a partner itself (its request >= 0)
    named_taken: int = 0  # of those, the partner it named was the one used (in range and active)

    def to_json(self) -> dict[str, int | float]:
        per = self.bytes / self.messages if self.messages else 0.0
        return {**self.__dict__, "bytes_per_message": per}


class V2VNetwork:
    """The V2V state of one route: each CAV's recent broadcasts (for latency) and the counters."""

    def __init__(
        self,
        occupancy: OccupancyConfig | None = None,
        link: LinkConfig | None = None,
        partners: PartnerConfig | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.occupancy = occupancy or OccupancyConfig()
        self.link = link or LinkConfig()
        self.partners = partners or PartnerConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.stats = LinkStats()
        self._history: dict[int, deque[tuple[int, np.ndarray, np.ndarray]]] = {}
        self._bytes = message_bytes(self.occupancy)

    def exchange(
        self,
        tick: int,
        cav_index: np.ndarray,
        pose: np.ndarray,
        own: np.ndarray,
        requested: np.ndarray | None = None,
    ) -> Exchange:
        """Broadcast this tick's own maps, pick partners, deliver and merge.

        ``cav_index`` (n,), ``pose`` (n, 3) x, y, yaw in the map frame, ``own`` (n, C, H, W) bool, and the
        partners the agent asked for at the last tick (n,) (-1: default)."""
        cav_index = np.asarray(cav_index, np.int64)
        pose = np.asarray(pose, np.float64).reshape(-1, 3)
        for j, cav in enumerate(cav_index):
            queue = self._history.setdefault(int(cav), deque(maxlen=self.link.latency_ticks + 1))
            queue.append((tick, pose[j].copy(), own[j]))
        partner = select_partners(pose[:, 0], pose[:, 1], pose[:, 2], cav_index, requested, self.partners)
        n = len(cav_index)
        self.stats.cav_ticks += n
        if requested is not None:
            asked = np.asarray(requested, np.int64) >= 0
            self.stats.named += int(asked.sum())
            self.stats.named_taken += int((asked & (partner == np.asarray(requested, np.int64))).sum())
        received = np.zeros(n, bool)
        sender_grid = np.zeros_like(own)
        sender_pose = np.zeros((n, 3))
        slot = {int(c): j for j, c in enumerate(cav_index)}
        for i in range(n):  # n <= 16 CAVs: the per-message bookkeeping is not a hot loop
            p = int(partner[i])
            if p == NO_PARTNER:
                continue
            self.stats.messages += 1
            self.stats.bytes += self._bytes
            message = self._message(p, tick)
            if message is None:
                self.stats.not_yet += 1
                continue
            if self.link.range_m is not None:
                if np.hypot(*(pose[i, :2] - pose[slot[p], :2])) > self.link.range_m:
                    self.stats.out_of_range += 1
                    continue
            if self.link.drop_rate > 0.0 and self.rng.random() < self.link.drop_rate:
                self.stats.dropped += 1
                continue
            sender_pose[i], sender_grid[i] = message
            received[i] = True
        self.stats.received += int(received.sum())
        merged = warp_and_merge(own, sender_grid, self._noisy(sender_pose), pose, received, self.occupancy)
        return Exchange(partner, received, merged)

    def _message(self, sender: int, tick: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The sender's (pose, grid) of tick ``tick - latency``, if it has one."""
        want = tick - self.link.latency_ticks
        for t, p, g in self._history.get(sender, ()):
            if t == want:
                return p, g
        return None

    def _noisy(self, pose: np.ndarray) -> np.ndarray:
        if self.link.pose_noise_m == 0.0 and self.link.pose_noise_deg == 0.0:
            return pose
        noise = self.rng.standard_normal(pose.shape)
        noise[:, :2] *= self.link.pose_noise_m
        noise[:, 2] *= np.radians(self.link.pose_noise_deg)
        return pose + noise
