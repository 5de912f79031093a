"""A Luxonis OAK camera as a source of spatial body keypoints (DepthAI v3 API).

``streamfix serve --source depthai[:KEY=VALUE,...]`` builds the pipeline below on the
first available device (or the one named by ``device=``) and reads the spatial
detection network's ``SpatialImgDetections`` on the host; the conversion to frames is
:mod:`streamfix.io.depthai_keypoints`. Options:

``model=ID|PATH``  (required with a device)
    A pose model with 17 (COCO) or 33 (BlazePose) keypoints: a Luxonis HubAI model id or
    a local NN archive (``.tar.xz``), as ``dai.node.SpatialDetectionNetwork.build`` takes it.
``fps=N``  (default 30)
    Camera and network frame rate, Hz; also the rate announced to the engine.
``device=ID``
    Device id or IP address (``dai.DeviceInfo``); default: the first device found.

Pipeline: colour camera (``CAM_A``) and a stereo pair (``StereoDepth`` with its own
cameras) into ``SpatialDetectionNetwork``; its ``out`` goes to a host queue. The device
is looked for first (``dai.Device.getAllAvailableDevices``, about half a second), so
with none attached the command fails at once with a message instead of waiting for
the library's connection timeout.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DepthaiOptions", "parse_depthai_spec", "import_depthai", "find_device", "check_device", "open_device_pipeline"]


@dataclass(frozen=True)
class DepthaiOptions:
    """``--source depthai:...`` settings (see the module docstring)."""

    model: str | None = None
    fps: float = 30.0
    device: str | None = None


def parse_depthai_spec(spec: str) -> DepthaiOptions:
    """``depthai`` or ``depthai:model=...,fps=30,device=...`` -> options; ValueError naming the bad part."""
    head, _, rest = spec.partition(":")
    if head != "depthai":
        raise ValueError(f"--source {spec!r} is not a depthai source")
    values: dict = {}
    for part in filter(None, (p.strip() for p in rest.split(","))):
        key, eq, value = part.partition("=")
        if not eq or key not in ("model", "fps", "device") or not value:
            raise ValueError(f"--source {spec!r}: {part!r} is not one of model=ID, fps=HZ, device=ID")
        values[key] = value
    if "fps" in values:
        try:
            values["fps"] = float(values["fps"])
        except ValueError:
            raise ValueError(f"--source {spec!r}: fps must be a number, got {values['fps']!r}") from None
        if not 0 < values["fps"] <= 240:
            raise ValueError(f"--source {spec!r}: fps must be in (0, 240] Hz, got {values['fps']:g}")
    return DepthaiOptions(**values)


def import_depthai():
    """The depthai module (v3); RuntimeError saying how to install it when absent or too old."""
    try:
        import depthai as dai
    except ImportError:
        raise RuntimeError("--source depthai needs the depthai package: pip install 'streamfix[depthai]'") from None
    if not hasattr(dai.node, "ThreadedHostNode"):
        raise RuntimeError(
            f"--source depthai needs depthai v3, found {getattr(dai, '__version__', 'an older version')}: "
            "pip install 'streamfix[depthai]'"
        )
    return dai


def find_device(dai, device: str | None = None):
    """The ``DeviceInfo`` to open; RuntimeError 'no DepthAI device found' when none is attached."""
    available = dai.Device.getAllAvailableDevices()
    if device is not None:
        for info in available:
            if device in (info.getDeviceId(), info.name):
                return info
        seen = ", ".join(f"{i.getDeviceId()} ({i.name})" for i in available) or "none"
        raise RuntimeError(f"no DepthAI device {device!r} found (devices found: {seen})")
    if not available:
        raise RuntimeError(
            "no DepthAI device found: connect an OAK camera (USB or PoE on this network) "
            "or pick another --source"
        )
    return available[0]


def check_device(options: DepthaiOptions):
    """``(dai, DeviceInfo)`` when ``options`` can open a device, without opening it; RuntimeError
    saying what is missing (the package, a device, a model) otherwise."""
    dai = import_depthai()
    info = find_device(dai, options.device)
    if options.model is None:
        raise RuntimeError(
            "--source depthai: name a pose model with model=HUBAI_ID or model=ARCHIVE.tar.xz "
            "(17 COCO or 33 BlazePose keypoints)"
        )
    return dai, info


def open_device_pipeline(options: DepthaiOptions):
    """Build and start the pipeline on a device: ``(pipeline, queue of SpatialImgDetections)``."""
    dai, info = check_device(options)
    pipeline = dai.Pipeline(dai.Device(info))
    camera = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
    stereo = pipeline.create(dai.node.StereoDepth).build(autoCreateCameras=True)
    network = pipeline.create(dai.node.SpatialDetectionNetwork).build(camera, stereo, options.model, fps=options.fps)
    queue = network.out.createOutputQueue(maxSize=8, blocking=False)
    pipeline.start()
    return pipeline, queue
