"""Automatic train regulation (ATR) core: traffic model, timetable, LQR / DHP / AOC (Lin 2010a).

ROS-free (numpy, scipy, torch).  Modules:

- :mod:`.blue_line` -- Taipei Blue line data (estimates, documented) and toy lines;
- :mod:`.traffic` -- Lin 2010a, eq. 1-6 (staggered departure-instant model) and the truth
  variant (saturation, crowding dwell, knock-on delays, exponential departure delays);
- :mod:`.tsk` -- multi-period TSK fuzzy model and timetable (eq. 7-10);
- :mod:`.cost` -- finite-service schedule-deviation cost (eq. 17-22, reconstructed);
- :mod:`.mlp`, :mod:`.problems`, :mod:`.training` -- AOC and DHP critic-actor training
  (eq. 23-49) on Exp. 1 (Narendra-Parthasarathy plant) and Exp. 2 (line regulation);
- :mod:`.regulators` -- ``make_regulator(name, line)`` with ``decide(x, step)`` for
  none / lqr / dhp / aoc, weights files;
- :mod:`.evaluation` -- closed-loop simulation and KPIs;
- :mod:`.node_core` -- :class:`~.node_core.AtsRegulatorCore` for the ``ats_regulator`` node.
"""
