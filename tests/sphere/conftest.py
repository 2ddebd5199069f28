"""The sphere tests share the light tests' synthetic maps and the bundled probe."""

from tests.light.conftest import grace, make_smooth, smooth, smooth_map  # noqa: F401
