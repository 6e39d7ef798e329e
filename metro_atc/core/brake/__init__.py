"""Brake-by-wire active safety diagnosis with an unscented Kalman filter.

Seed 000, second paper (Lin & Tang).  ROS-free core of the ``brake_diagnostic`` node:

* :mod:`.ukf` - generic scaled UKF (alpha 0.5, beta 2, kappa 3 - L; eq. 7-8), batch
  variant and the linear Kalman filter used to check it;
* :mod:`.paper_vehicle` - the paper's E-class SUV (Table I): truth plant, vehicle-tyre
  reference model (eq. 6 tables) and the 26-state diagnostic observer (eq. 1-10);
* :mod:`.metro_car` - the metro 4-axle brake-by-wire variant with wheel-rail adhesion
  and :class:`~.metro_car.MetroBrakeObserver`, the stateful class the node uses;
* :mod:`.diagnosis` - residual evaluation and decision logic (thresholds from normal
  runs' statistics);
* :mod:`.checks`, :mod:`.experiments` - verification problems and the Monte-Carlo
  reproduction behind ``python -m metro_atc.bench.ukf``.
"""
