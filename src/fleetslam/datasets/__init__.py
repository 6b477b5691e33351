"""RGB-D sources: TUM folders, simulator exports and MCAP recordings; one module each, loaded lazily."""

from fleetslam.datasets.base import LOADERS, Intrinsics, RGBDFrame, RGBDSource, guess_kind, open_source

__all__ = ["LOADERS", "Intrinsics", "RGBDFrame", "RGBDSource", "guess_kind", "open_source"]
