"""OptiTrack NatNet: Motive's UDP stream format (:mod:`.format`, pure), the sensor adapter
publishing its rigid bodies as SRG edges (:mod:`.adapter`) and the client side of its command
and data channels (:mod:`.link`)."""
