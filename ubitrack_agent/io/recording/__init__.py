"""Recording what the providers announce and publish to an MCAP file, and replaying it.

An MCAP file (https://mcap.dev/spec) written by ``ubitrack record`` has the profile
:data:`~.layout.PROFILE` and three kinds of channel (:mod:`.layout`):

* ``/ubitrack/announcements`` (JSON): each provider's SRG fragment when its liveliness token
  appeared, and its withdrawal when the token went, so the SRG can be rebuilt at any instant;
* ``/ubitrack/data/<provider>/<edge>`` (msgpack): every measurement of a measured edge, the
  bytes as they travelled (``core.codec``: timestamps, values and covariances bit-exact); the
  message's ``log_time`` is when the recorder received it, its ``publish_time`` the
  measurement's timestamp;
* ``/ubitrack/tf/<provider>/<edge>`` (protobuf ``foxglove.FrameTransform``), for viewers, one per
  6D or 3D edge: parent frame the edge's source, child frame its target.

:mod:`.writer` writes such a file, :mod:`.reader` reads and validates one (any malformed input
is a :class:`~.layout.RecordingError`), :mod:`.recorder` fills a writer from zenoh and
:mod:`.replayer` announces and publishes a recording again. The ``mcap`` extra
(``pip install "ubitrack-agent[mcap]"``) brings the MCAP library and Foxglove's schemas.
"""
