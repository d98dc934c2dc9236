from embagents.bench import cases_actors  # noqa: F401
