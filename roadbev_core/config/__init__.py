"""Configuration: the grid and the rig (the one source of truth for each), the typed config tree
of the pipeline and the node, and the params-file reader.

* :class:`GridSpec` (``grid``): the BEV grid in the road frame;
* :class:`StereoCamera` (``rig``): the rectified stereo rig;
* :class:`RoadbevConfig` (``tree``): every setting, read from ROS parameters and validated once;
* :func:`load_params_file` (``params_file``): a ROS 2 params YAML -> flat parameters.
"""

from roadbev_core.config.grid import GRID_PRESETS, ConfigError, GridSpec, grid_preset
from roadbev_core.config.params_file import (
    NODE_NAME,
    ParamError,
    ParamsFile,
    load_params_file,
    parse_assignments,
    split_backend_spec,
)
from roadbev_core.config.rig import RSRD_CROP_TOP, StereoCamera
from roadbev_core.config.tree import (
    BASE_FRAME,
    DEFAULT_BACKEND,
    GRID_PARAMS,
    MAX_GRID_VOXELS,
    MAX_IMAGE_PIXELS,
    MAX_SYNC_SETS,
    BackendConfig,
    DiagnosticsConfig,
    FarFieldConfig,
    ImuConfig,
    MapConfig,
    ParamSpec,
    PreviewConfig,
    RoadbevConfig,
    SyncConfig,
    TopicsConfig,
    VehicleConfig,
    check_image_size,
    parameter_specs,
)

__all__ = [
    "BASE_FRAME",
    "DEFAULT_BACKEND",
    "GRID_PARAMS",
    "GRID_PRESETS",
    "MAX_GRID_VOXELS",
    "MAX_IMAGE_PIXELS",
    "MAX_SYNC_SETS",
    "NODE_NAME",
    "RSRD_CROP_TOP",
    "BackendConfig",
    "ConfigError",
    "DiagnosticsConfig",
    "FarFieldConfig",
    "GridSpec",
    "ImuConfig",
    "MapConfig",
    "ParamError",
    "ParamSpec",
    "ParamsFile",
    "PreviewConfig",
    "RoadbevConfig",
    "StereoCamera",
    "SyncConfig",
    "TopicsConfig",
    "VehicleConfig",
    "check_image_size",
    "grid_preset",
    "load_params_file",
    "parameter_specs",
    "parse_assignments",
    "split_backend_spec",
]
