"""Build profile replay-cli (GENERATED from buildflags/matrix.toml)."""

from typing import Any

PROFILE: dict[str, Any] = {'flags': {'BUILD_MATCHER_ALIKED_LIGHTGLUE': {'distribution': 'c3-matcher-aliked-lightglue', 'state': 'ON', 'strategy': 'aliked_lightglue'}, 'BUILD_MATCHER_DISK_LIGHTGLUE': {'distribution': 'c3-matcher-disk-lightglue', 'state': 'ON', 'strategy': 'disk_lightglue'}, 'BUILD_MATCHER_XFEAT': {'distribution': 'c3-matcher-xfeat', 'state': 'ON', 'strategy': 'xfeat'}}, 'name': 'replay-cli', 'strict': False, 'tools': 'c3-matcher-tools'}
