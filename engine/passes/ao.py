"""Ambient-occlusion pass: cosine-weighted hemisphere rays of length ao_radius, unoccluded fraction."""

from .raypass import RayPass, ray_bindings
from .shadows import record_split


class AOPass(RayPass):
    name = "ao"
    shader = "ao.comp"
    bindings = ray_bindings("ao", "ao.raw")
    # postponed leaf tests on every device: AO rays are short and end in leaves often (faster on GPUs too, unlike
    # the shadow pass's, which keeps the device default)
    postpone_leaves = True

    def record(self, rec, targets, reference_samples=None):
        """This frame's `ao_samples` rays per pixel, or `reference_samples` split over several dispatches."""
        if reference_samples:
            record_split(rec, self, targets, 1, 1, int(reference_samples))
        else:
            self.dispatch_rows(rec, targets, [0, 0, 0, 0, 0])
