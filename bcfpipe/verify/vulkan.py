"""The batch decoder on Vulkan (issue 60): the shipped SPIR-V, bcfpipe/decoders/bcf_decode_N.spv, which
is the shipped HLSL (glsl/bcf_decode.comp through SPIR-V and SPIRV-Cross) compiled back by glslang's
HLSL front end (`bcfpipe shaders`), run as a compute pipeline; the feature layers as BC6H / BC7
images with the material's sampler (trilinear, its addressing per axis); on any Vulkan 1.1 device
with BC textures: a GPU's driver, or Mesa's lavapipe on the CPU. `bcfpipe verify --runtime vulkan`
holds it to decoder.onnx as it holds OpenGL, so the HLSL an engine takes is what is checked.

The same calls as `bcfpipe.verify.glsl.GLRuntime` that verify makes: ``load``, ``decode``,
``decode_grad``, ``unload``, ``release`` and ``info``.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from bcfpipe.errors import Unavailable
from bcfpipe.formats import dds
from bcfpipe.verify.spirv import HLSL_SAMPLER_BINDING, shipped_kernel
from bcfpipe.verify.glsl import LOCAL_SIZE, MaterialDesc, wrap_codes

PARAMS = struct.Struct("<IiII2i2f2IfI")  # bcf_decode.comp's BcfParams before uLodBias: 48 bytes
TEXTURE_BINDING = 4  # the layers' images (register t4..); their samplers at HLSL_SAMPLER_BINDING
MAX_GROUPS = 65535  # maxComputeWorkGroupCount[0] every Vulkan device has


class VulkanUnavailable(Unavailable):
    """No Vulkan device with BC textures here (one line, exit 2)."""


@dataclass
class _Buffer:
    buffer: Any
    memory: Any
    size: int


@dataclass
class VkMaterial:
    """A material on the device: its layers' images and views, one sampler, its weight words."""

    desc: MaterialDesc
    images: list = field(default_factory=list)  # (image, memory, view) per layer
    sampler: Any = None
    weights: _Buffer | None = None


class VulkanRuntime:
    """One device and queue; a compute pipeline per layer count, made on first use from
    ``kernel(layers)``: by default the shipped SPIR-V (bcfpipe/decoders/bcf_decode_N.spv), or any
    kernel with its resources (examples/hlsl/bcf_include_kernel.hlsl). ``combined``: the kernel
    takes the textures as combined image samplers at binding 4 (glslang's SPIR-V of the GLSL, which
    SPIRV-Cross translates), not separate images and samplers (an HLSL kernel's)."""

    def __init__(self, kernel: Callable[[int], bytes] = shipped_kernel, combined: bool = False) -> None:
        self.kernel, self.combined = kernel, combined
        try:
            import vulkan as vk  # lazy: start-up
        except (ImportError, OSError) as e:
            raise VulkanUnavailable(f"the vulkan package or libvulkan is missing ({e}): "
                                    "pip install vulkan; apt-get install libvulkan1 mesa-vulkan-drivers") from None
        self.vk = vk
        try:
            app = vk.VkApplicationInfo(pApplicationName="bcfpipe", applicationVersion=1, pEngineName="bcfpipe",
                                       engineVersion=1, apiVersion=vk.VK_MAKE_VERSION(1, 1, 0))
            self.instance = vk.vkCreateInstance(vk.VkInstanceCreateInfo(pApplicationInfo=app), None)
        except Exception as e:  # noqa: BLE001 - no loader, no ICD: no Vulkan here
            raise VulkanUnavailable(f"no Vulkan instance: {type(e).__name__}: {e}") from None
        picked = None
        for pd in vk.vkEnumeratePhysicalDevices(self.instance):
            if not vk.vkGetPhysicalDeviceFeatures(pd).textureCompressionBC:
                continue
            families = vk.vkGetPhysicalDeviceQueueFamilyProperties(pd)
            q = next((i for i, f in enumerate(families) if f.queueFlags & vk.VK_QUEUE_COMPUTE_BIT), None)
            if q is not None:
                picked = (pd, q)
                break
        if picked is None:
            vk.vkDestroyInstance(self.instance, None)
            raise VulkanUnavailable("no Vulkan device with BC textures and a compute queue")
        self.physical, self.family = picked
        props = vk.vkGetPhysicalDeviceProperties(self.physical)
        v = props.apiVersion
        self._info = {"renderer": props.deviceName, "version": f"Vulkan {v >> 22}.{(v >> 12) & 0x3FF}.{v & 0xFFF}",
                      "vendor": f"0x{props.vendorID:04X}"}
        queue = vk.VkDeviceQueueCreateInfo(queueFamilyIndex=self.family, queueCount=1, pQueuePriorities=[1.0])
        features = vk.VkPhysicalDeviceFeatures(textureCompressionBC=vk.VK_TRUE)
        self.device = vk.vkCreateDevice(self.physical, vk.VkDeviceCreateInfo(
            queueCreateInfoCount=1, pQueueCreateInfos=[queue], pEnabledFeatures=features), None)
        self.queue = vk.vkGetDeviceQueue(self.device, self.family, 0)
        self.pool = vk.vkCreateCommandPool(self.device, vk.VkCommandPoolCreateInfo(
            queueFamilyIndex=self.family, flags=vk.VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT), None)
        self.memory = vk.vkGetPhysicalDeviceMemoryProperties(self.physical)
        self._pipelines: dict[int, tuple] = {}

    @property
    def info(self) -> dict[str, str]:
        return dict(self._info)

    # ------------------------------------------------------------------ memory
    def _memory_type(self, bits: int, want: int) -> int:
        for i in range(self.memory.memoryTypeCount):
            if bits & (1 << i) and (self.memory.memoryTypes[i].propertyFlags & want) == want:
                return i
        raise VulkanUnavailable("no host-visible, coherent Vulkan memory")

    def _buffer(self, size: int, usage: int) -> _Buffer:
        vk = self.vk
        size = max(16, size)
        buf = vk.vkCreateBuffer(self.device, vk.VkBufferCreateInfo(size=size, usage=usage,
                                                                   sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE), None)
        req = vk.vkGetBufferMemoryRequirements(self.device, buf)
        host = vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | vk.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
        mem = vk.vkAllocateMemory(self.device, vk.VkMemoryAllocateInfo(
            allocationSize=req.size, memoryTypeIndex=self._memory_type(req.memoryTypeBits, host)), None)
        vk.vkBindBufferMemory(self.device, buf, mem, 0)
        return _Buffer(buf, mem, size)

    def _write(self, b: _Buffer, data: bytes) -> None:
        mapped = self.vk.vkMapMemory(self.device, b.memory, 0, b.size, 0)
        mapped[:len(data)] = data
        self.vk.vkUnmapMemory(self.device, b.memory)

    def _read(self, b: _Buffer, n: int) -> bytes:
        mapped = self.vk.vkMapMemory(self.device, b.memory, 0, b.size, 0)
        out = bytes(mapped[:n])
        self.vk.vkUnmapMemory(self.device, b.memory)
        return out

    def _free(self, b: _Buffer | None) -> None:
        if b is not None:
            self.vk.vkDestroyBuffer(self.device, b.buffer, None)
            self.vk.vkFreeMemory(self.device, b.memory, None)

    def _submit(self, record) -> None:
        """Record commands through ``record(cmd)``, run them, wait."""
        vk = self.vk
        cmd = vk.vkAllocateCommandBuffers(self.device, vk.VkCommandBufferAllocateInfo(
            commandPool=self.pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY, commandBufferCount=1))[0]
        fence = vk.vkCreateFence(self.device, vk.VkFenceCreateInfo(), None)
        try:
            vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo(flags=vk.VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT))
            record(cmd)
            vk.vkEndCommandBuffer(cmd)
            vk.vkQueueSubmit(self.queue, 1, [vk.VkSubmitInfo(commandBufferCount=1, pCommandBuffers=[cmd])], fence)
            vk.vkWaitForFences(self.device, 1, [fence], vk.VK_TRUE, 0xFFFFFFFFFFFFFFFF)
        finally:
            vk.vkDestroyFence(self.device, fence, None)
            vk.vkFreeCommandBuffers(self.device, self.pool, 1, [cmd])

    # ------------------------------------------------------------------ textures
    def _format(self, tex: dds.DdsTexture) -> int:
        vk = self.vk
        if tex.is_bc7:
            return vk.VK_FORMAT_BC7_UNORM_BLOCK
        return vk.VK_FORMAT_BC6H_SFLOAT_BLOCK if tex.signed else vk.VK_FORMAT_BC6H_UFLOAT_BLOCK

    def _image(self, tex: dds.DdsTexture):
        """``tex``'s whole chain as a sampled image (its mip count: the sampler's lod clamp, as
        GL_TEXTURE_MAX_LEVEL) and a view of it."""
        vk = self.vk
        fmt, n = self._format(tex), len(tex.levels)
        _, w0, h0 = tex.levels[0]
        img = vk.vkCreateImage(self.device, vk.VkImageCreateInfo(
            imageType=vk.VK_IMAGE_TYPE_2D, format=fmt, extent=vk.VkExtent3D(w0, h0, 1), mipLevels=n, arrayLayers=1,
            samples=vk.VK_SAMPLE_COUNT_1_BIT, tiling=vk.VK_IMAGE_TILING_OPTIMAL,
            usage=vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT | vk.VK_IMAGE_USAGE_SAMPLED_BIT,
            sharingMode=vk.VK_SHARING_MODE_EXCLUSIVE, initialLayout=vk.VK_IMAGE_LAYOUT_UNDEFINED), None)
        req = vk.vkGetImageMemoryRequirements(self.device, img)
        mem = vk.vkAllocateMemory(self.device, vk.VkMemoryAllocateInfo(
            allocationSize=req.size, memoryTypeIndex=self._memory_type(req.memoryTypeBits, 0)), None)
        vk.vkBindImageMemory(self.device, img, mem, 0)
        data = b"".join(np.ascontiguousarray(b, np.uint8).tobytes() for b, _, _ in tex.levels)
        staging = self._buffer(len(data), vk.VK_BUFFER_USAGE_TRANSFER_SRC_BIT)
        self._write(staging, data)
        whole = vk.VkImageSubresourceRange(aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, baseMipLevel=0, levelCount=n,
                                           baseArrayLayer=0, layerCount=1)
        regions, offset = [], 0
        for k, (blocks, w, h) in enumerate(tex.levels):
            regions.append(vk.VkBufferImageCopy(
                bufferOffset=offset, bufferRowLength=0, bufferImageHeight=0,
                imageSubresource=vk.VkImageSubresourceLayers(aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, mipLevel=k,
                                                             baseArrayLayer=0, layerCount=1),
                imageOffset=vk.VkOffset3D(0, 0, 0), imageExtent=vk.VkExtent3D(w, h, 1)))
            offset += int(np.asarray(blocks).nbytes)

        def barrier(old, new, src, dst):
            return vk.VkImageMemoryBarrier(srcAccessMask=src, dstAccessMask=dst, oldLayout=old, newLayout=new,
                                           srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
                                           dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED, image=img,
                                           subresourceRange=whole)

        def record(cmd):
            vk.vkCmdPipelineBarrier(cmd, vk.VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, 0,
                                    0, None, 0, None, 1, [barrier(vk.VK_IMAGE_LAYOUT_UNDEFINED,
                                                                  vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 0,
                                                                  vk.VK_ACCESS_TRANSFER_WRITE_BIT)])
            vk.vkCmdCopyBufferToImage(cmd, staging.buffer, img, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                                      len(regions), regions)
            vk.vkCmdPipelineBarrier(cmd, vk.VK_PIPELINE_STAGE_TRANSFER_BIT, vk.VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                                    0, 0, None, 0, None, 1, [barrier(vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                                                                     vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                                                                     vk.VK_ACCESS_TRANSFER_WRITE_BIT,
                                                                     vk.VK_ACCESS_SHADER_READ_BIT)])
        try:
            self._submit(record)
        finally:
            self._free(staging)
        identity = vk.VK_COMPONENT_SWIZZLE_IDENTITY
        view = vk.vkCreateImageView(self.device, vk.VkImageViewCreateInfo(
            image=img, viewType=vk.VK_IMAGE_VIEW_TYPE_2D, format=fmt,
            components=vk.VkComponentMapping(identity, identity, identity, identity), subresourceRange=whole), None)
        return img, mem, view

    def _sampler(self, wrap) -> Any:
        """Trilinear, mag linear, ``wrap``'s addressing per axis (repeat, clamp to edge, mirrored)."""
        vk = self.vk
        modes = {0: vk.VK_SAMPLER_ADDRESS_MODE_REPEAT, 1: vk.VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE,
                 2: vk.VK_SAMPLER_ADDRESS_MODE_MIRRORED_REPEAT}
        s, t = wrap_codes(wrap)
        return vk.vkCreateSampler(self.device, vk.VkSamplerCreateInfo(
            magFilter=vk.VK_FILTER_LINEAR, minFilter=vk.VK_FILTER_LINEAR, mipmapMode=vk.VK_SAMPLER_MIPMAP_MODE_LINEAR,
            addressModeU=modes[s], addressModeV=modes[t], addressModeW=vk.VK_SAMPLER_ADDRESS_MODE_REPEAT,
            mipLodBias=0.0, anisotropyEnable=vk.VK_FALSE, maxAnisotropy=1.0, compareEnable=vk.VK_FALSE,
            compareOp=vk.VK_COMPARE_OP_ALWAYS, minLod=0.0, maxLod=vk.VK_LOD_CLAMP_NONE,
            borderColor=vk.VK_BORDER_COLOR_FLOAT_TRANSPARENT_BLACK, unnormalizedCoordinates=vk.VK_FALSE), None)

    # ------------------------------------------------------------------ materials
    def load(self, m: MaterialDesc, weights: bytes | None = None) -> VkMaterial:
        """Upload ``m``'s feature layers and its weight buffer (``weights`` overrides the file)."""
        vm = VkMaterial(m)
        try:
            for tex in m.layer_textures():
                vm.images.append(self._image(tex))
            vm.sampler = self._sampler(m.wrap)
            data = weights if weights is not None else m.weights_file.read_bytes()
            vm.weights = self._buffer(len(data) + 4, self.vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT)
            self._write(vm.weights, data + b"\0" * (-len(data) % 4))
        except BaseException:
            self.unload(vm)
            raise
        return vm

    def unload(self, vm: VkMaterial) -> None:
        vk = self.vk
        for img, mem, view in vm.images:
            vk.vkDestroyImageView(self.device, view, None)
            vk.vkDestroyImage(self.device, img, None)
            vk.vkFreeMemory(self.device, mem, None)
        vm.images = []
        if vm.sampler is not None:
            vk.vkDestroySampler(self.device, vm.sampler, None)
            vm.sampler = None
        self._free(vm.weights)
        vm.weights = None

    def _texture_bindings(self) -> list[tuple[int, int]]:
        """(binding, descriptor type) of the layers' textures and samplers."""
        vk = self.vk
        if self.combined:
            return [(TEXTURE_BINDING, vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER)]
        return [(TEXTURE_BINDING, vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE),
                (HLSL_SAMPLER_BINDING, vk.VK_DESCRIPTOR_TYPE_SAMPLER)]

    def _pipeline(self, layers: int) -> tuple:
        """(descriptor set layout, pipeline layout, pipeline) for ``layers`` feature layers."""
        if layers in self._pipelines:
            return self._pipelines[layers]
        vk = self.vk
        stage = vk.VK_SHADER_STAGE_COMPUTE_BIT
        bindings = [vk.VkDescriptorSetLayoutBinding(binding=b, descriptorType=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                                                    descriptorCount=1, stageFlags=stage) for b in range(4)]
        bindings += [vk.VkDescriptorSetLayoutBinding(binding=b, descriptorType=t, descriptorCount=layers,
                                                     stageFlags=stage) for b, t in self._texture_bindings()]
        dsl = vk.vkCreateDescriptorSetLayout(self.device, vk.VkDescriptorSetLayoutCreateInfo(
            bindingCount=len(bindings), pBindings=bindings), None)
        layout = vk.vkCreatePipelineLayout(self.device, vk.VkPipelineLayoutCreateInfo(
            setLayoutCount=1, pSetLayouts=[dsl]), None)
        code = self.kernel(layers)
        module = vk.vkCreateShaderModule(self.device, vk.VkShaderModuleCreateInfo(codeSize=len(code), pCode=code), None)
        # the stage info is copied into the pipeline's by value: it must outlive the call, or its
        # pName points at freed memory (python-vulkan keeps a struct's own pointers alive only)
        shader = vk.VkPipelineShaderStageCreateInfo(stage=stage, module=module, pName="main")
        try:
            pipe = vk.vkCreateComputePipelines(self.device, vk.VK_NULL_HANDLE, 1, [vk.VkComputePipelineCreateInfo(
                stage=shader, layout=layout)], None)[0]
        finally:
            vk.vkDestroyShaderModule(self.device, module, None)
        self._pipelines[layers] = (dsl, layout, pipe)
        return self._pipelines[layers]

    def _run(self, vm: VkMaterial, queries: np.ndarray, count: int, grad: bool,
             grid: tuple[int, int] = (0, 0), grid_lod: float = 0.0) -> np.ndarray:
        vk = self.vk
        m = vm.desc
        stride = m.c_out
        groups = -(-count // LOCAL_SIZE)
        if groups > MAX_GROUPS:
            raise ValueError(f"{count} samples exceed one dispatch; decode in chunks")
        dsl, layout, pipe = self._pipeline(len(vm.images))
        ws, wt = wrap_codes(m.wrap)
        params = PARAMS.pack(m.weight_offset, m.normal_index, count, stride, ws, wt, *map(float, m.ref_size),
                             *grid, float(grid_lod), int(grad)) + struct.pack(f"<{len(m.lod_biases)}f", *m.lod_biases)
        q = np.ascontiguousarray(queries, np.float32).tobytes()
        usage = vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT
        bufs = [self._buffer(len(q), usage), self._buffer(count * stride * 4, usage), self._buffer(len(params), usage)]
        n = len(vm.images)
        textures = self._texture_bindings()
        pool = vk.vkCreateDescriptorPool(self.device, vk.VkDescriptorPoolCreateInfo(
            maxSets=1, poolSizeCount=1 + len(textures), pPoolSizes=[
                vk.VkDescriptorPoolSize(type=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, descriptorCount=4),
                *(vk.VkDescriptorPoolSize(type=t, descriptorCount=n) for _, t in textures)]), None)
        try:
            self._write(bufs[0], q)
            self._write(bufs[2], params)
            ds = vk.vkAllocateDescriptorSets(self.device, vk.VkDescriptorSetAllocateInfo(
                descriptorPool=pool, descriptorSetCount=1, pSetLayouts=[dsl]))[0]
            writes = [vk.VkWriteDescriptorSet(dstSet=ds, dstBinding=k, dstArrayElement=0, descriptorCount=1,
                                              descriptorType=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                                              pBufferInfo=[vk.VkDescriptorBufferInfo(buffer=b.buffer, offset=0,
                                                                                     range=b.size)])
                      for k, b in enumerate([vm.weights, *bufs])]
            for binding, kind in textures:  # the views, the sampler, or both in one descriptor
                view = kind != vk.VK_DESCRIPTOR_TYPE_SAMPLER
                sampler = kind != vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE
                writes.append(vk.VkWriteDescriptorSet(
                    dstSet=ds, dstBinding=binding, dstArrayElement=0, descriptorCount=n, descriptorType=kind,
                    pImageInfo=[vk.VkDescriptorImageInfo(
                        sampler=vm.sampler if sampler else None, imageView=v if view else None,
                        imageLayout=vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL) for _, _, v in vm.images]))
            vk.vkUpdateDescriptorSets(self.device, len(writes), writes, 0, None)

            def record(cmd):
                vk.vkCmdBindPipeline(cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, pipe)
                vk.vkCmdBindDescriptorSets(cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, layout, 0, 1, [ds], 0, None)
                vk.vkCmdDispatch(cmd, groups, 1, 1)

            self._submit(record)
            return np.frombuffer(self._read(bufs[1], count * stride * 4), np.float32).reshape(count, stride).copy()
        finally:
            vk.vkDestroyDescriptorPool(self.device, pool, None)
            for b in bufs:
                self._free(b)

    def decode(self, vm: VkMaterial, uv: np.ndarray, s: np.ndarray | float, chunk: int = 1 << 20) -> np.ndarray:
        """Decode at points ``uv`` (N, 2) and lods ``s`` (N,) or scalar -> (N, c_out) float32."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        q = np.zeros((len(uv), 4), np.float32)
        q[:, :2], q[:, 2] = uv, np.broadcast_to(np.asarray(s, np.float32), (len(uv),))
        return self._chunks(vm, q, chunk, grad=False)

    def decode_grad(self, vm: VkMaterial, uv: np.ndarray, duvdx: np.ndarray, duvdy: np.ndarray,
                    chunk: int = 1 << 20) -> np.ndarray:
        """Decode with s from the uv derivatives (bcfDecodeGrad) -> (N, c_out) float32."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        q = np.zeros((len(uv), 2, 4), np.float32)
        q[:, 0, :2], q[:, 0, 2:] = uv, np.asarray(duvdx, np.float32).reshape(-1, 2)
        q[:, 1, :2] = np.asarray(duvdy, np.float32).reshape(-1, 2)
        return self._chunks(vm, q, chunk, grad=True)

    def decode_grid(self, vm: VkMaterial, width: int, height: int, lod: float) -> np.ndarray:
        """The texel centres of a width x height grid at lod ``lod`` -> (height, width, c_out), row 0
        at v = 0.5 / height (the shader's grid mode: no queries), in bands of rows past one dispatch."""
        rows = max(1, MAX_GROUPS * LOCAL_SIZE // width)
        out = []
        for y0 in range(0, height, rows):
            n = min(rows, height - y0)
            if y0 == 0 and n == height:
                return self._run(vm, np.zeros((1, 4), np.float32), width * height, False, (width, height),
                                 lod).reshape(height, width, -1)
            yy, xx = np.meshgrid((np.arange(y0, y0 + n) + 0.5) / height, (np.arange(width) + 0.5) / width,
                                 indexing="ij")
            out.append(self.decode(vm, np.stack([xx.ravel(), yy.ravel()], 1), lod).reshape(n, width, -1))
        return np.concatenate(out)

    def _chunks(self, vm: VkMaterial, q: np.ndarray, chunk: int, grad: bool) -> np.ndarray:
        parts = [self._run(vm, q[a:a + chunk], min(chunk, len(q) - a), grad) for a in range(0, len(q), chunk)]
        return np.concatenate(parts) if parts else np.zeros((0, vm.desc.c_out), np.float32)

    def release(self) -> None:
        vk = self.vk
        for dsl, layout, pipe in self._pipelines.values():
            vk.vkDestroyPipeline(self.device, pipe, None)
            vk.vkDestroyPipelineLayout(self.device, layout, None)
            vk.vkDestroyDescriptorSetLayout(self.device, dsl, None)
        self._pipelines = {}
        vk.vkDestroyCommandPool(self.device, self.pool, None)
        vk.vkDestroyDevice(self.device, None)
        vk.vkDestroyInstance(self.instance, None)

    def __enter__(self) -> "VulkanRuntime":
        return self

    def __exit__(self, *exc) -> None:
        self.release()
