"""The live agent (paper section 5.2.1, the Ubitrack Middleware Agent) rebuilt on zenoh.

* :mod:`.announcements` - providers' SRG fragments into validated SRG edges (pure);
* :mod:`.flows` - plan every queried relation (a recalibration without its stored edges) and
  merge the data flows (pure);
* :mod:`.materialise` - data flow components into worker specifications (pure);
* :mod:`.reconcile` - the start / stop / update actions between running and wanted (pure);
* :mod:`.hosts` - the host managers: starting and stopping workers over zenoh;
* :mod:`.liveness` - data liveness: edges whose data stopped count as gone (pure);
* :mod:`.problems` - rejections and handler failures: counted, logged rate-limited, guarded;
* :mod:`.runtime` - the agent itself: liveliness, fragments, replanning, reconciling.
"""
