"""The twin's dynamics checked against measurement: time-series experiments on any device
(:mod:`twin.dynamics.protocols`), their dataset on disk (:mod:`twin.dynamics.series`), their
replay on the twin (:mod:`twin.dynamics.replay`) and the dynamic effect the twin misses, named
and fitted (:mod:`twin.dynamics.calibrate`). ``twin dynamics record|replay|calibrate`` drive them.
"""
