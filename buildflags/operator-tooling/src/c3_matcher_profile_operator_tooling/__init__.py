"""Build profile operator-tooling (GENERATED from buildflags/matrix.toml)."""

from typing import Any

PROFILE: dict[str, Any] = {'flags': {'BUILD_MATCHER_ALIKED_LIGHTGLUE': {'distribution': 'c3-matcher-aliked-lightglue', 'state': 'OFF', 'strategy': 'aliked_lightglue'}, 'BUILD_MATCHER_DISK_LIGHTGLUE': {'distribution': 'c3-matcher-disk-lightglue', 'state': 'OFF', 'strategy': 'disk_lightglue'}, 'BUILD_MATCHER_XFEAT': {'distribution': 'c3-matcher-xfeat', 'state': 'OFF', 'strategy': 'xfeat'}}, 'name': 'operator-tooling', 'strict': True, 'tools': 'c3-matcher-tools'}
