"""The client layer: the sensor and application APIs (:class:`Provider`, :class:`Relation`)
and real sources and sinks (the A.R.T. DTrack2 adapter, the static-edges file)."""
