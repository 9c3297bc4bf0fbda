"""The library's part that knows the UAV world (``uav_ipp``): the paper's policies and the DAgger
warm start. The algorithm (:mod:`sb3_coma.coma`) imports nothing from here nor from the world."""

from sb3_coma.uav.policies import CBAMPolicy, UavCnnPolicy, UavCOMAPolicy

__all__ = ["CBAMPolicy", "UavCOMAPolicy", "UavCnnPolicy"]
