"""Route-set authoring, apart from evaluation: the tools that write route files, which the evaluator
never imports.

``route_gen`` adds CAVs around a scenario route and generates scenario-free routes; ``benchmark_gen``
draws the benchmark route sets by the rules of ``route_rules``, with flow locations from
``flow_places``; both place routes with ``route_geometry``. ``bench2drive`` imports single-ego
Bench2Drive / Leaderboard 2.0 route files; ``interdrive`` the multi-vehicle scenario folders of
InterDrive and MDrive-style benchmarks, with ``import_repair``'s small changes where our planner needs
them. Checking a route file (``cmudrive.bench.route_check``) stays beside the evaluator, which runs the
same checks before a run.
"""
