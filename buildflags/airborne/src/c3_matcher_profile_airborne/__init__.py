"""Build profile airborne (GENERATED from buildflags/matrix.toml)."""

from typing import Any

PROFILE: dict[str, Any] = {'flags': {'BUILD_MATCHER_ALIKED_LIGHTGLUE': {'distribution': 'c3-matcher-aliked-lightglue', 'state': 'ON', 'strategy': 'aliked_lightglue'}, 'BUILD_MATCHER_DISK_LIGHTGLUE': {'distribution': 'c3-matcher-disk-lightglue', 'state': 'ON', 'strategy': 'disk_lightglue'}, 'BUILD_MATCHER_XFEAT': {'distribution': 'c3-matcher-xfeat', 'state': 'WIRED', 'strategy': 'xfeat'}}, 'name': 'airborne', 'strict': True, 'tools': None}
