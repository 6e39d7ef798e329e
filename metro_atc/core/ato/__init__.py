"""ATO core (ROS-free): energy-efficient speed-profile planning and speed tracking.

Planning (Ke 2010 MAX-MIN ant system, ACTP n.d. coasting control, a dynamic-programming
reference optimum) and tracking (Li n.d. fuzzy logic speed controller on a 5-region reference
motion curve, and a PI tracker for comparison).  The ROS node ``ato_controller`` wraps
:class:`metro_atc.core.ato.onboard.OnboardAto`, whose every control step is the compiled
step of :mod:`.control_kernel_step` (the one source of the control law).

Modules
-------
- :mod:`.envelope`: run geometry (direction, grades, limits), operating limits and the speed
  envelope (speed limits incl. train length, braking curves, programmed station stopping).
- :mod:`.strategy`: distance-step simulator of driving strategies (traction / cruise /
  coast with closed-form coasting, ACTP n.d., eq. 7-8) and the profile evaluator.
- :mod:`.sections`, :mod:`.mmas`: Ke 2010 pre-work tables and the MAX-MIN ant system.
- :mod:`.coasting`: ACTP n.d. FOTP / FCTP / ECTP / ACTP-TC / ACTP-C.
- :mod:`.dp`: dynamic-programming minimum-energy reference for a given running time.
- :mod:`.reference_curve`, :mod:`.fuzzy`, :mod:`.pi`, :mod:`.tracking`: Li n.d. tracking.
- :mod:`.planner`, :mod:`.controller`: one planning interface and the stateful node core.
- :mod:`.onboard`, :mod:`.control_kernel`, :mod:`.control_kernel_step`,
  :mod:`.control_kernel_pack`: the on-board ATO and its compiled control step.
"""
