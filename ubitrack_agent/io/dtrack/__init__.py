"""A.R.T. DTrack2/DTRACK3: the ASCII UDP output format (:mod:`.format`, pure) and the sensor
adapter publishing it as SRG edges (:mod:`.adapter`)."""
