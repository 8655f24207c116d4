"""DDS tests' helpers: the loopback-only namespace, the ROS 2 venv, the scenario peers."""

import pytest

# judge.py asserts on behalf of the tests: let pytest explain its failures.
pytest.register_assert_rewrite("tests.interop.ros2_interop.judge")
