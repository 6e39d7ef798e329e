"""A metro service day, ROS-free: terminus interlocking, train circulation, periods of a day.

- :mod:`metro_atc.core.service.interlocking`: route-based interlocking of a terminus;
- :mod:`metro_atc.core.service.circulation`: minimum-fleet train circulation over a trip list;
- :mod:`metro_atc.core.service.day`: the day of TSK periods (Lin 2010a, eq. 7-10);
- :mod:`metro_atc.core.service.records`: what a day leaves (stop calls, turnbacks, depot);
- :mod:`metro_atc.core.service.turnback`: the turnback link (earliest next departure,
  inherited delay);
- :mod:`metro_atc.core.service.planned`: records of the planned day with injected delays;
- :mod:`metro_atc.core.service.daykpi`: the day's KPIs per period and direction;
- :mod:`metro_atc.core.service.dayplots`: train graph, circulation chart, KPI table;
- :mod:`metro_atc.core.service.regulation`: Lin 2010a, Exp. 2 through the turnback.
"""
