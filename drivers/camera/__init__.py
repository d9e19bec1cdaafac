"""Cameras: the ``Camera`` protocol and ``Frame`` (base), the V4L2 driver, stable USB identity, the stereo pair and
the simulated camera.

    from drivers.camera import CameraSettings, StereoCamera, V4L2Camera, resolve_camera

    left = V4L2Camera(resolve_camera("usb-port:1-2.1").capture_node, CameraSettings(pixel_format="MJPG",
                      width_px=1920, height_px=1080, fps=30, exposure_us=8000, gain=0, white_balance_k=4600,
                      focus=0))
    right = V4L2Camera(resolve_camera("usb-port:1-2.2").capture_node, ...)
    with StereoCamera(left, right) as pair:
        pair.flush()                 # after every rig move
        stereo = pair.capture_pair() # stereo.left / stereo.right are Frames, stereo.dt_s the skew
"""

from drivers.camera.base import (
    Camera,
    CameraAccessDenied,
    CameraBandwidthError,
    CameraBase,
    CameraBusy,
    CameraError,
    CameraGone,
    CameraNotFound,
    CameraSettings,
    CaptureFailed,
    ControlNotAccepted,
    Frame,
)
from drivers.camera.stereo import StereoCamera, StereoFrame, StereoSkewError
from drivers.camera.synthetic import CameraFault, SyntheticCamera
from drivers.camera.usb_identity import (
    AmbiguousCameraSpec,
    CameraDevice,
    CameraRegistry,
    DeviceScan,
    UnstableCameraName,
    UsbIdentity,
    list_cameras,
    resolve_camera,
    usb_reset,
)
from drivers.camera.v4l2 import V4L2Camera

__all__ = [
    "AmbiguousCameraSpec",
    "Camera",
    "CameraAccessDenied",
    "CameraBandwidthError",
    "CameraBase",
    "CameraBusy",
    "CameraDevice",
    "CameraError",
    "CameraFault",
    "CameraGone",
    "CameraNotFound",
    "CameraRegistry",
    "CameraSettings",
    "CaptureFailed",
    "ControlNotAccepted",
    "DeviceScan",
    "Frame",
    "StereoCamera",
    "StereoFrame",
    "StereoSkewError",
    "SyntheticCamera",
    "UnstableCameraName",
    "UsbIdentity",
    "V4L2Camera",
    "list_cameras",
    "resolve_camera",
    "usb_reset",
]
