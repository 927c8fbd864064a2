"""The physical systems, one package each: physics, its fast kernels beside it, the estimators
named for what they estimate, the seed reproduction with its report and figures, and the
system's CLI commands.

Nothing in the engine (:mod:`rulkit.estimation`, :mod:`rulkit.prognosis`, :mod:`rulkit.model`,
:mod:`rulkit.integrate`, :mod:`rulkit.metrics`) imports from here; a test checks the import graph.
"""
