"""Where a whiskered robot goes next: a free-space grid of what its rods swept
(`free_space.FreeSpace`) and the planners of its exploration (`explorer.Explorer`), as a
library without processes, messages or files (numpy, scipy, scikit-image)."""

from vibrissa.planning.explorer import PLANNERS, Explorer, ExploreSettings, Plan
from vibrissa.planning.free_space import FREE, HIDDEN, OCCUPIED, UNKNOWN, FreeSpace

__all__ = ["FREE", "HIDDEN", "OCCUPIED", "PLANNERS", "UNKNOWN", "ExploreSettings", "Explorer", "FreeSpace",
           "Plan"]
