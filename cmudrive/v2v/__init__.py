"""V2V: partner selection, warping a partner's occupancy into the ego frame, merging, and the link model.

Typical use, per tick for the ``n`` active CAVs::

    from cmudrive.v2v import V2VNetwork
    net = V2VNetwork()                                   # one per route
    ex = net.exchange(tick, cav_index, poses, own_grids, requested_partners)
    ex.partner, ex.merged                                # (n,), (n, C, H, W)
"""

from cmudrive.v2v.link import Exchange, LinkConfig, LinkStats, V2VNetwork, message_bytes
from cmudrive.v2v.partner import NO_PARTNER, PartnerConfig, select_partners
from cmudrive.v2v.warp import merge, warp_and_merge, warp_to_ego

__all__ = [
    "NO_PARTNER",
    "Exchange",
    "LinkConfig",
    "LinkStats",
    "PartnerConfig",
    "V2VNetwork",
    "merge",
    "message_bytes",
    "select_partners",
    "warp_and_merge",
    "warp_to_ego",
]
