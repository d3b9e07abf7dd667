"""Applications that only call the generated kernels (layer 8, beside :mod:`derive.reports`):
reachability maps and base placement (:mod:`derive.apps.reach`)."""
