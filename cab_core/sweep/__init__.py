"""Sweeps: many attempts from one configuration (``cab -m ...``): the manifest that pins a sweep,
where each attempt writes, the supervisor that runs each attempt in a child process, and the state
of an attempt's folder as resume sees it."""
