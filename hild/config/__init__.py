"""The config room: the robot file's schema, its loader, and the ``Params`` base for plugins.

pyyaml and pydantic are imported here and nowhere else.
"""

from hild.config.loader import ConfigError, ConfigIssue, LoadedConfig, json_schema, load_config
from hild.config.model import RobotConfig
from hild.config.params import Field, Params

__all__ = ["ConfigError", "ConfigIssue", "Field", "LoadedConfig", "Params", "RobotConfig", "json_schema", "load_config"]
