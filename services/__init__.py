"""Pattern services: the algorithms behind spatial relationship patterns, and the worker runtime.

* :mod:`services.algorithms` - pure maths, arrays in and out, no dataflow dependency.
* :mod:`services.registry` - the services the agent may launch, by registered name.
* :mod:`services.spec` - the component specification a worker is started with.
* :mod:`services.worker` - one OS process per pattern instance, wired over zenoh.
"""
