"""Control laws shared by the simulators and the onboard followers (seed 002 §1.2.5).

Pure functions and small state machines with an injected clock: proportional and integral actions with the
seed's three anti-windup thresholds (:mod:`control.laws`), a P+I(+D) controller (:mod:`control.pid`),
linearisation of a casadi model (:mod:`control.linearize`) and discrete LQR (:mod:`control.lqr`).
"""
