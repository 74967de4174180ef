"""Pattern services: the algorithms behind spatial relationship patterns, and the worker runtime.

* :mod:`ubitrack_agent.services.algorithms` - pure maths, arrays in and out, no dataflow dependency.
* :mod:`ubitrack_agent.services.registry` - the services the agent may launch, by registered name.
* :mod:`ubitrack_agent.services.spec` - the component specification a worker is started with.
* :mod:`ubitrack_agent.services.worker` - one OS process per pattern instance, wired over zenoh.
"""
