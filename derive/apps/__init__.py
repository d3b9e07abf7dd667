"""Applications that only call the generated kernels (layer 8, beside :mod:`derive.reports`):
reachability maps and base placement (:mod:`derive.apps.reach`, figures in
:mod:`derive.apps.plots`) and Cartesian paths to joint paths and URScript
(:mod:`derive.apps.path`)."""
