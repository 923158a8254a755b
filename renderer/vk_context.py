"""A headless Vulkan 1.3 instance and device on lavapipe, with optional validation.

No window, no surface, no swapchain: everything renders into images that are read back.
The device enables the Vulkan 1.3 features ``dynamicRendering`` and ``synchronization2``.

With ``validation=True`` the Khronos validation layer is enabled (plus synchronization
validation) and a debug-utils messenger collects every message into
:attr:`VkContext.messages`. The Python binding supports only **one** debug callback per
process, so the callback is a module-level function appending to a module-level list; each
context remembers where its messages start. Exceptions inside the callback would be swallowed
by cffi, so the callback only appends, and callers assert afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from assetpipe.core.errors import RenderError

from ._vk import INSTALL_HINT, load_vulkan

VALIDATION_LAYER = "VK_LAYER_KHRONOS_validation"

# Every debug-utils message of the process, in order: (severity name, message text).
_MESSAGES: list[tuple[str, str]] = []
_SEVERITY = {0x1: "VERBOSE", 0x10: "INFO", 0x100: "WARNING", 0x1000: "ERROR"}


def _debug_callback(severity: int, types: int, data: Any, user: Any) -> int:
    """The process's one debug-utils callback: append and return VK_FALSE."""
    vk = load_vulkan()
    try:
        text = vk.ffi.string(data.pMessage).decode("utf-8", "replace") if data.pMessage else ""
    except Exception:  # noqa: BLE001 - never let anything escape into cffi
        text = "<unreadable message>"
    _MESSAGES.append((_SEVERITY.get(int(severity), str(severity)), text))
    return 0


@dataclass
class Buffer:
    """A buffer with its own memory (lavapipe has one host-visible, coherent memory type)."""

    ctx: "VkContext"
    handle: Any
    memory: Any
    size: int

    def write(self, data: np.ndarray | bytes, offset: int = 0) -> None:
        """Copy ``data`` into the buffer at ``offset`` (bytes)."""
        vk = self.ctx.vk
        raw = np.frombuffer(memoryview(data).cast("B") if not isinstance(data, np.ndarray)
                            else np.ascontiguousarray(data).view(np.uint8).reshape(-1), np.uint8)
        if offset + raw.size > self.size:
            raise RenderError(f"write of {raw.size} bytes at {offset} overflows a {self.size}-byte buffer")
        if raw.size == 0:
            return
        ptr = vk.vkMapMemory(self.ctx.device, self.memory, offset, raw.size, 0)
        np.frombuffer(ptr, np.uint8)[:] = raw
        vk.vkUnmapMemory(self.ctx.device, self.memory)

    def read(self, size: int | None = None) -> np.ndarray:
        """A copy of the first ``size`` bytes (copied out before unmapping)."""
        vk = self.ctx.vk
        n = self.size if size is None else size
        ptr = vk.vkMapMemory(self.ctx.device, self.memory, 0, n, 0)
        out = np.frombuffer(ptr, np.uint8).copy()
        vk.vkUnmapMemory(self.ctx.device, self.memory)
        return out

    def destroy(self) -> None:
        vk = self.ctx.vk
        if self.handle is not None:
            vk.vkDestroyBuffer(self.ctx.device, self.handle, None)
            vk.vkFreeMemory(self.ctx.device, self.memory, None)
            self.handle = None


@dataclass
class Image:
    """A 2D image with its memory and one view over all its mip levels."""

    ctx: "VkContext"
    handle: Any
    memory: Any
    view: Any
    width: int
    height: int
    levels: int
    format: int
    aspect: int

    def destroy(self) -> None:
        vk = self.ctx.vk
        if self.handle is not None:
            vk.vkDestroyImageView(self.ctx.device, self.view, None)
            vk.vkDestroyImage(self.ctx.device, self.handle, None)
            vk.vkFreeMemory(self.ctx.device, self.memory, None)
            self.handle = None


@dataclass
class DeviceInfo:
    """What was selected: name, driver and API versions."""

    name: str
    api_version: str
    driver_version: int
    extensions: list[str] = field(default_factory=list)


class VkContext:
    """Instance, lavapipe device, one graphics queue and a command pool.

    Use as a context manager or call :meth:`close`. ``messages`` lists the validation
    messages received since this context was created.
    """

    def __init__(self, validation: bool = True, sync_validation: bool = True,
                 app_name: str = "assetpipe-renderer") -> None:
        self.vk = vk = load_vulkan()
        self.validation = False
        self._msg_start = len(_MESSAGES)
        self._messenger = None
        self.instance = None
        self.device = None
        self._closed = False

        layers: list[str] = []
        extensions: list[str] = []
        if validation:
            available = {p.layerName for p in vk.vkEnumerateInstanceLayerProperties()}
            if VALIDATION_LAYER not in available:
                raise RenderError(f"the Khronos validation layer is not installed: {INSTALL_HINT}")
            layers.append(VALIDATION_LAYER)
            extensions.append(vk.VK_EXT_DEBUG_UTILS_EXTENSION_NAME)
            self.validation = True

        app = vk.VkApplicationInfo(pApplicationName=app_name, applicationVersion=1,
                                   pEngineName="assetpipe", engineVersion=1,
                                   apiVersion=vk.VK_MAKE_VERSION(1, 3, 0))
        p_next = None
        if validation:
            messenger_info = self._messenger_info()
            p_next = messenger_info
            if sync_validation:
                enables = [vk.VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT]
                p_next = vk.VkValidationFeaturesEXT(
                    pNext=messenger_info, enabledValidationFeatureCount=len(enables),
                    pEnabledValidationFeatures=enables)
        info = vk.VkInstanceCreateInfo(pNext=p_next, pApplicationInfo=app,
                                       enabledLayerCount=len(layers), ppEnabledLayerNames=layers,
                                       enabledExtensionCount=len(extensions),
                                       ppEnabledExtensionNames=extensions)
        try:
            self.instance = vk.vkCreateInstance(info, None)
        except vk.VkError as exc:
            raise RenderError(f"vkCreateInstance failed ({type(exc).__name__}): {INSTALL_HINT}") from exc
        try:
            if validation:
                create = vk.vkGetInstanceProcAddr(self.instance, "vkCreateDebugUtilsMessengerEXT")
                self._messenger = create(self.instance, self._messenger_info(), None)
            self._pick_device()
            self._create_device()
        except BaseException:
            self.close()
            raise

    # ----------------------------------------------------------------------------- set-up
    def _messenger_info(self) -> Any:
        vk = self.vk
        return vk.VkDebugUtilsMessengerCreateInfoEXT(
            messageSeverity=(vk.VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT
                             | vk.VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT),
            messageType=(vk.VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT
                         | vk.VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT
                         | vk.VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT),
            pfnUserCallback=_debug_callback)

    def _pick_device(self) -> None:
        vk = self.vk
        devices = vk.vkEnumeratePhysicalDevices(self.instance)
        if not devices:
            raise RenderError(f"no Vulkan device found (lavapipe missing?): {INSTALL_HINT}")
        chosen = None
        for dev in devices:
            props = vk.vkGetPhysicalDeviceProperties(dev)
            name = vk.ffi.string(props.deviceName).decode() if not isinstance(props.deviceName, str) \
                else props.deviceName
            if "llvmpipe" in name or chosen is None:
                chosen = (dev, props, name)
        dev, props, name = chosen  # type: ignore[misc]
        api = props.apiVersion
        major, minor = api >> 22, (api >> 12) & 0x3FF
        if (major, minor) < (1, 3):
            raise RenderError(f"device {name} supports Vulkan {major}.{minor}, 1.3 is required: "
                              f"{INSTALL_HINT}")
        self.physical_device = dev
        self.info = DeviceInfo(name=name, api_version=f"{major}.{minor}.{api & 0xFFF}",
                               driver_version=int(props.driverVersion))
        self.limits = props.limits
        self.memory_props = vk.vkGetPhysicalDeviceMemoryProperties(dev)
        families = vk.vkGetPhysicalDeviceQueueFamilyProperties(dev)
        for i, fam in enumerate(families):
            if fam.queueFlags & vk.VK_QUEUE_GRAPHICS_BIT:
                self.queue_family = i
                break
        else:
            raise RenderError(f"device {name} has no graphics queue")

    def _create_device(self) -> None:
        vk = self.vk
        f13 = vk.VkPhysicalDeviceVulkan13Features(dynamicRendering=vk.VK_TRUE,
                                                  synchronization2=vk.VK_TRUE)
        queue = vk.VkDeviceQueueCreateInfo(queueFamilyIndex=self.queue_family, queueCount=1,
                                           pQueuePriorities=[1.0])
        have = vk.vkGetPhysicalDeviceFeatures(self.physical_device)
        # block-compressed textures (BC, ETC2): enabled when the device has them
        features = vk.VkPhysicalDeviceFeatures(samplerAnisotropy=vk.VK_TRUE,
                                               textureCompressionBC=have.textureCompressionBC,
                                               textureCompressionETC2=have.textureCompressionETC2)
        info = vk.VkDeviceCreateInfo(pNext=f13, queueCreateInfoCount=1, pQueueCreateInfos=[queue],
                                     pEnabledFeatures=features)
        self.device = vk.vkCreateDevice(self.physical_device, info, None)
        self.queue = vk.vkGetDeviceQueue(self.device, self.queue_family, 0)
        self.command_pool = vk.vkCreateCommandPool(self.device, vk.VkCommandPoolCreateInfo(
            flags=vk.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT,
            queueFamilyIndex=self.queue_family), None)
        self.command_buffer = vk.vkAllocateCommandBuffers(self.device, vk.VkCommandBufferAllocateInfo(
            commandPool=self.command_pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY,
            commandBufferCount=1))[0]
        self.fence = vk.vkCreateFence(self.device, vk.VkFenceCreateInfo(), None)

    # ------------------------------------------------------------------------- messages
    @property
    def messages(self) -> list[tuple[str, str]]:
        """Validation messages (severity, text) received since this context was created."""
        return list(_MESSAGES[self._msg_start:])

    def take_messages(self) -> list[tuple[str, str]]:
        """The messages received since the last call (or creation), then forget them."""
        out = list(_MESSAGES[self._msg_start:])
        self._msg_start = len(_MESSAGES)
        return out

    # -------------------------------------------------------------------------- memory
    def _memory_type(self, bits: int, flags: int) -> int:
        props = self.memory_props
        for i in range(props.memoryTypeCount):
            if bits & (1 << i) and (props.memoryTypes[i].propertyFlags & flags) == flags:
                return i
        raise RenderError("no suitable Vulkan memory type")

    def _allocate(self, requirements: Any, flags: int) -> Any:
        vk = self.vk
        info = vk.VkMemoryAllocateInfo(allocationSize=requirements.size,
                                       memoryTypeIndex=self._memory_type(requirements.memoryTypeBits, flags))
        return vk.vkAllocateMemory(self.device, info, None)

    def create_buffer(self, size: int, usage: int) -> Buffer:
        """A host-visible, coherent buffer of ``size`` bytes (at least 4)."""
        vk = self.vk
        size = max(int(size), 4)
        handle = vk.vkCreateBuffer(self.device, vk.VkBufferCreateInfo(
            size=size, usage=usage, sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None)
        req = vk.vkGetBufferMemoryRequirements(self.device, handle)
        memory = self._allocate(req, vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT
                                | vk.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)
        vk.vkBindBufferMemory(self.device, handle, memory, 0)
        return Buffer(self, handle, memory, size)

    def can_sample(self, fmt: int) -> bool:
        """The device can copy into, sample and linearly filter optimal-tiling images of ``fmt``."""
        vk = self.vk
        # SAMPLED_IMAGE | SAMPLED_IMAGE_FILTER_LINEAR | TRANSFER_DST (the python module lacks the
        # core name of the last one)
        need = (vk.VK_FORMAT_FEATURE_SAMPLED_IMAGE_BIT | vk.VK_FORMAT_FEATURE_SAMPLED_IMAGE_FILTER_LINEAR_BIT
                | 0x00008000)
        props = vk.vkGetPhysicalDeviceFormatProperties(self.physical_device, fmt)
        return (props.optimalTilingFeatures & need) == need

    def create_image(self, width: int, height: int, fmt: int, usage: int, levels: int = 1,
                     aspect: int | None = None) -> Image:
        """A device-local optimal-tiling 2D image and a view over all its levels."""
        vk = self.vk
        aspect = vk.VK_IMAGE_ASPECT_COLOR_BIT if aspect is None else aspect
        handle = vk.vkCreateImage(self.device, vk.VkImageCreateInfo(
            imageType=vk.VK_IMAGE_TYPE_2D, format=fmt,
            extent=vk.VkExtent3D(width=width, height=height, depth=1), mipLevels=levels,
            arrayLayers=1, samples=vk.VK_SAMPLE_COUNT_1_BIT, tiling=vk.VK_IMAGE_TILING_OPTIMAL,
            usage=usage, sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE,
            initialLayout=vk.VK_IMAGE_LAYOUT_UNDEFINED), None)
        req = vk.vkGetImageMemoryRequirements(self.device, handle)
        memory = self._allocate(req, vk.VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT)
        vk.vkBindImageMemory(self.device, handle, memory, 0)
        view = vk.vkCreateImageView(self.device, vk.VkImageViewCreateInfo(
            image=handle, viewType=vk.VK_IMAGE_VIEW_TYPE_2D, format=fmt,
            subresourceRange=vk.VkImageSubresourceRange(aspectMask=aspect, baseMipLevel=0,
                                                        levelCount=levels, baseArrayLayer=0,
                                                        layerCount=1)), None)
        return Image(self, handle, memory, view, width, height, levels, fmt, aspect)

    # ------------------------------------------------------------------------ commands
    def submit(self, record: Callable[[Any], None]) -> None:
        """Record commands with ``record(cmd)`` into the context's command buffer, submit, wait."""
        vk = self.vk
        cmd = self.command_buffer
        vk.vkResetCommandBuffer(cmd, 0)
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo(
            flags=vk.VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT))
        record(cmd)
        vk.vkEndCommandBuffer(cmd)
        vk.vkResetFences(self.device, 1, [self.fence])
        submit = vk.VkSubmitInfo2(commandBufferInfoCount=1, pCommandBufferInfos=[
            vk.VkCommandBufferSubmitInfo(commandBuffer=cmd)])
        vk.vkQueueSubmit2(self.queue, 1, [submit], self.fence)
        vk.vkWaitForFences(self.device, 1, [self.fence], vk.VK_TRUE, 60_000_000_000)

    def image_barrier(self, cmd: Any, image: Image, old: int, new: int, src_stage: int,
                      src_access: int, dst_stage: int, dst_access: int,
                      base_level: int = 0, levels: int | None = None) -> None:
        """One synchronization2 image layout transition."""
        vk = self.vk
        barrier = vk.VkImageMemoryBarrier2(
            srcStageMask=src_stage, srcAccessMask=src_access, dstStageMask=dst_stage,
            dstAccessMask=dst_access, oldLayout=old, newLayout=new,
            srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED, dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
            image=image.handle,
            subresourceRange=vk.VkImageSubresourceRange(
                aspectMask=image.aspect, baseMipLevel=base_level,
                levelCount=image.levels - base_level if levels is None else levels,
                baseArrayLayer=0, layerCount=1))
        vk.vkCmdPipelineBarrier2(cmd, vk.VkDependencyInfo(imageMemoryBarrierCount=1,
                                                          pImageMemoryBarriers=[barrier]))

    def memory_barrier(self, cmd: Any, src_stage: int, src_access: int, dst_stage: int,
                       dst_access: int) -> None:
        """A global synchronization2 memory barrier."""
        vk = self.vk
        barrier = vk.VkMemoryBarrier2(srcStageMask=src_stage, srcAccessMask=src_access,
                                      dstStageMask=dst_stage, dstAccessMask=dst_access)
        vk.vkCmdPipelineBarrier2(cmd, vk.VkDependencyInfo(memoryBarrierCount=1,
                                                          pMemoryBarriers=[barrier]))

    # ------------------------------------------------------------------------- teardown
    def wait_idle(self) -> None:
        if self.device is not None:
            self.vk.vkDeviceWaitIdle(self.device)

    def close(self) -> None:
        """Destroy the device, messenger and instance (leaks are reported here by the layer)."""
        if self._closed:
            return
        self._closed = True
        vk = self.vk
        if self.device is not None:
            vk.vkDeviceWaitIdle(self.device)
            vk.vkDestroyFence(self.device, self.fence, None)
            vk.vkDestroyCommandPool(self.device, self.command_pool, None)
            vk.vkDestroyDevice(self.device, None)
            self.device = None
        if self._messenger is not None:
            destroy = vk.vkGetInstanceProcAddr(self.instance, "vkDestroyDebugUtilsMessengerEXT")
            destroy(self.instance, self._messenger, None)
            self._messenger = None
        if self.instance is not None:
            vk.vkDestroyInstance(self.instance, None)
            self.instance = None

    def __enter__(self) -> "VkContext":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
