"""The image-based visual servo under its earlier name (remote controllers import it from here): the law is
:mod:`cdpr.laws.ibvs`."""

from cdpr.laws.ibvs import IbvsCore, desired_image, fit_pose, frame_needed, ibvs_from_scenario

__all__ = ["IbvsCore", "desired_image", "fit_pose", "frame_needed", "ibvs_from_scenario"]
