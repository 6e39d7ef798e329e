"""The hand CDR codecs of the messages sent without a message object, one module each.

:mod:`~metro_atc.nodes.wire.cdr` holds the byte helpers, the one size limit and the
layouts read from the generated message classes; :mod:`~metro_atc.nodes.wire.fleet_state`,
:mod:`~metro_atc.nodes.wire.fleet_command` and :mod:`~metro_atc.nodes.wire.fleet_sensors`
(the lockstep messages) each hold their message's encode, decode and conversions to and
from the core; :mod:`~metro_atc.nodes.wire.traction_command` the per-train command echo.
"""
