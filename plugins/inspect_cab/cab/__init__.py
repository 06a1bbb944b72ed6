"""The names Inspect gives this distribution's task, scorer and metric (``cab/codeaction``,
``cab/verdict``, ``cab/wilson``): Inspect namespaces a registered object by the top-level package
that defines it, so they are defined in :mod:`cab._registry`; the code is in :mod:`inspect_cab`."""
