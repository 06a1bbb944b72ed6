"""The robot API: the paper's tools implemented once over the Simulator, Planner and Embodiment
contracts. Handlers take a :class:`~cab_core.robot.context.RobotContext` and a validated pydantic
argument model and return a JSON-able payload; images travel as observation ids."""
