"""The scenarios of one route: built at setup, stepped before every world tick.

:func:`build_scenarios` turns a route's ``<scenario>`` elements into :class:`Scenario` objects of the
registered types (``REGISTRY``); types not implemented yet are kept as names only and make the record say
``scenario_simulated: false``. Setup errors (a trigger point off CAV 0's route, an unknown or
out-of-range parameter, a map with no place for the scenario) raise :class:`ScenarioError` naming the
route, the scenario and the parameter.
"""

from __future__ import annotations

import numpy as np

from cmudrive.bench.criteria import RouteCriteria
from cmudrive.bench.routes import RouteSpec
from cmudrive.bench.scenarios.actorflows import (
    EnterActorFlow,
    HighwayExit,
    InterurbanActorFlow,
    InterurbanAdvancedActorFlow,
    MergerIntoSlowTraffic,
    MergerIntoSlowTrafficV2,
)
from cmudrive.bench.scenarios.adversaries import OppositeVehicleRunningRedLight, OppositeVehicleTakingPriority
from cmudrive.bench.scenarios.base import Phase, RouteProgress, Scenario, ScenarioConfig, ScenarioContext
from cmudrive.bench.scenarios.bicycles import CrossingBicycleFlow
from cmudrive.bench.scenarios.crossings import (
    DynamicObjectCrossing,
    ParkingCrossingPedestrian,
    PedestrianCrossing,
    VehicleTurningRoute,
    VehicleTurningRoutePedestrian,
)
from cmudrive.bench.scenarios.cutins import HighwayCutIn, ParkingCutIn, StaticCutIn
from cmudrive.bench.scenarios.emergency import YieldToEmergencyVehicle
from cmudrive.bench.scenarios.invading import InvadingTurn
from cmudrive.bench.scenarios.junctions import (
    BlockedIntersection,
    ControlLoss,
    HardBreakRoute,
    SequentialLaneChange,
    T_Junction,
    VanillaNonSignalizedTurn,
    VanillaNonSignalizedTurnEncounterStopsign,
    VanillaSignalizedTurnEncounterGreenLight,
    VanillaSignalizedTurnEncounterRedLight,
)
from cmudrive.bench.scenarios.obstacles import (
    Accident,
    AccidentTwoWays,
    ConstructionObstacle,
    ConstructionObstacleTwoWays,
    HazardAtSideLane,
    HazardAtSideLaneTwoWays,
    ParkedObstacle,
    ParkedObstacleTwoWays,
    VehicleOpensDoorTwoWays,
)
from cmudrive.bench.scenarios.parking import ParkingExit
from cmudrive.bench.scenarios.turns import (
    NonSignalizedJunctionLeftTurn,
    NonSignalizedJunctionLeftTurnEnterFlow,
    NonSignalizedJunctionRightTurn,
    SignalizedJunctionLeftTurn,
    SignalizedJunctionLeftTurnEnterFlow,
    SignalizedJunctionRightTurn,
)
from cmudrive.maps import RoadMap, Route
from cmudrive.sim.dynamics import Controls
from cmudrive.sim.snapshot import Snapshot
from cmudrive.sim.world import World

REGISTRY: dict[str, type[Scenario]] = {
    cls.type_name: cls
    for cls in (
        Accident,
        AccidentTwoWays,
        ConstructionObstacle,
        ConstructionObstacleTwoWays,
        HazardAtSideLane,
        HazardAtSideLaneTwoWays,
        ParkedObstacle,
        ParkedObstacleTwoWays,
        DynamicObjectCrossing,
        ParkingCrossingPedestrian,
        PedestrianCrossing,
        VehicleTurningRoute,
        VehicleTurningRoutePedestrian,
        HighwayCutIn,
        ParkingCutIn,
        StaticCutIn,
        YieldToEmergencyVehicle,
        BlockedIntersection,
        ControlLoss,
        HardBreakRoute,
        SequentialLaneChange,
        EnterActorFlow,
        HighwayExit,
        InterurbanActorFlow,
        MergerIntoSlowTraffic,
        MergerIntoSlowTrafficV2,
        T_Junction,
        VanillaNonSignalizedTurn,
        VanillaNonSignalizedTurnEncounterStopsign,
        VanillaSignalizedTurnEncounterGreenLight,
        VanillaSignalizedTurnEncounterRedLight,
        NonSignalizedJunctionLeftTurn,
        NonSignalizedJunctionLeftTurnEnterFlow,
        NonSignalizedJunctionRightTurn,
        SignalizedJunctionLeftTurn,
        SignalizedJunctionLeftTurnEnterFlow,
        SignalizedJunctionRightTurn,
        OppositeVehicleRunningRedLight,
        OppositeVehicleTakingPriority,
        VehicleOpensDoorTwoWays,
        InvadingTurn,
        ParkingExit,
        InterurbanAdvancedActorFlow,
        CrossingBicycleFlow,
    )
}


class ScenarioManager:
    """All scenarios of one route; :meth:`update` once per tick with the latest snapshot."""

    def __init__(self, scenarios: list[Scenario], unsupported: list[str], routes: list[Route]) -> None:
        self.scenarios, self.unsupported = scenarios, unsupported
        self.progress = RouteProgress(routes)

    @property
    def simulated(self) -> bool | None:
        """None without scenarios; True when every scenario of the route has behaviour here."""
        if not self.scenarios and not self.unsupported:
            return None
        return not self.unsupported

    def update(self, snap: Snapshot) -> None:
        if not self.scenarios:
            return
        self.progress.update(snap)
        for scenario in self.scenarios:
            scenario.step(snap, self.progress)

    def perturb(self, controls: Controls, cav: np.ndarray) -> Controls:
        """The agent's controls for the CAVs ``cav`` after the active scenarios changed them (ControlLoss)."""
        for scenario in self.scenarios:
            if scenario.phase == Phase.ACTIVE:
                controls = scenario.perturb(controls, cav, self.progress)
        return controls

    def finish(self) -> None:
        """The route ended: end every scenario still running (actors removed, blocked tests resumed)."""
        for scenario in self.scenarios:
            scenario.finish()


def build_scenarios(
    spec: RouteSpec,
    world: World | None,
    road_map: RoadMap,
    routes: list[Route],
    criteria: RouteCriteria | None,
    config: ScenarioConfig | None = None,
) -> ScenarioManager:
    """The route's scenarios, placed on the map (ScenarioError when one cannot be). Without a world and
    criteria the scenarios are placed for their :meth:`Scenario.plan` only (:func:`plan_scenarios`)."""
    ctx = ScenarioContext(
        spec.id,
        world,
        road_map,
        routes,
        criteria,
        np.random.default_rng([spec.seed, 2]),  # the scenarios' own stream: traffic is unchanged
        config or ScenarioConfig(),
    )
    built, unsupported = [], []
    for sc in spec.scenarios:
        cls = REGISTRY.get(sc.type)
        if cls is None:
            unsupported.append(sc.type)
        else:
            built.append(cls(sc, ctx))
    return ScenarioManager(built, unsupported, routes)


def plan_scenarios(spec: RouteSpec, road_map: RoadMap, routes: list[Route]) -> ScenarioManager:
    """The route's scenarios placed as the evaluator places them (same random stream), without a world:
    for their plans (what they will spawn and where); stepping them raises."""
    return build_scenarios(spec, None, road_map, routes, None)
