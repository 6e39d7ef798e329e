"""A metro service day, ROS-free: terminus interlocking, train circulation, periods of a day.

- :mod:`metro_atc.core.service.interlocking`: route-based interlocking of a terminus;
- :mod:`metro_atc.core.service.circulation`: minimum-fleet train circulation over a trip list;
- :mod:`metro_atc.core.service.day`: the day of TSK periods (Lin 2010a, eq. 7-10).
"""
