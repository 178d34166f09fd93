"""Print pyproject.toml's runtime, dev and cluster requirements, one a line (single source of
truth): `make setup` installs them all, so CI runs the `pano4d batch` tests on Ray."""

import tomllib
from pathlib import Path

project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
extras = project["optional-dependencies"]
print("\n".join(project["dependencies"] + extras["dev"] + extras["cluster"]))
