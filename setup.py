"""Where the packages come from: the repository keeps its top-level folders (``services/``,
``sim_trackers/``, ``templates/``), and they install as subpackages of ``ubitrack_agent``, so
no folder of a user's and no other distribution with a generic top-level name (``services``,
``templates``) can shadow them (issue [newcomer]; setuptools' ``package_dir`` mapping,
https://setuptools.pypa.io/en/latest/userguide/package_discovery.html). The rest of the
configuration is in ``pyproject.toml``; this file exists only because the list of mapped
packages is found, not written out by hand."""

from setuptools import find_packages, setup

MAPPED = ("services", "sim_trackers", "templates")
"""Top-level folders of the repository that install as ``ubitrack_agent.<folder>``."""

mapped = find_packages(include=[f"{name}*" for name in MAPPED])
setup(
    packages=[
        *find_packages(include=["ubitrack_agent*"]),
        *(f"ubitrack_agent.{p}" for p in mapped),
    ],
    package_dir={f"ubitrack_agent.{name}": name for name in MAPPED},
)
