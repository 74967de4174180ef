"""Suite-wide settings: hypothesis without per-example deadlines (these machines are shared and
noisy; speed is measured by bench/, never asserted by tests)."""

from hypothesis import settings

settings.register_profile("ubitrack", deadline=None)
settings.load_profile("ubitrack")
