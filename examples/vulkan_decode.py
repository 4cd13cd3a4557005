"""An engine's-eye decoder: a built bcfpipe material to PNG images at a chosen lod, on Vulkan, with the
shipped SPIR-V (bcfpipe/decoders/bcf_decode_N.spv) and nothing of bcfpipe's code.

It does what an engine's compute pass does, from docs/format.md alone: parse material.json, upload
each feature layer's BC7 / BC6H mip chain to an image, make the material's sampler (trilinear, its
addressing per axis), bind the weight record, fill the kernel's parameter block, and dispatch one
tile of texels at a time (queries of (u, v, s), as a material evaluated at arbitrary uv would be).
Outputs: one PNG per semantic (albedo.png, normal.png, ...), the source's values (value_scale,
value_bias; a normal as 0.5 n + 0.5) in 8 bits, as `bcfpipe decode` writes its 8-bit images.

    python examples/vulkan_decode.py OUT/materials/Bricks -o tiles/ --lod 0 --size 512

Needs numpy, the vulkan package (pip install vulkan) and a Vulkan 1.1 driver with BC textures (a
GPU's, or Mesa's lavapipe: apt-get install mesa-vulkan-drivers). A material's classic outputs (a
layout's BC textures) are not the kernel's work and are left out.
"""
from __future__ import annotations

import argparse
import json
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import vulkan as vk

DXGI_TO_VK = {95: vk.VK_FORMAT_BC6H_UFLOAT_BLOCK, 96: vk.VK_FORMAT_BC6H_SFLOAT_BLOCK, 98: vk.VK_FORMAT_BC7_UNORM_BLOCK}
WRAP = {"repeat": (0, vk.VK_SAMPLER_ADDRESS_MODE_REPEAT), "clamp": (1, vk.VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE),
        "mirror": (2, vk.VK_SAMPLER_ADDRESS_MODE_MIRRORED_REPEAT)}
SAMPLER_BINDING = 12  # the shipped SPIR-V's samplers: docs/format.md, Other APIs


def read_dds(path: Path) -> tuple[int, int, int, list[bytes]]:
    """(DXGI format, width, height, the mip levels' block data) of a DX10-header DDS."""
    data = path.read_bytes()
    if data[:4] != b"DDS " or data[84:88] != b"DX10":
        sys.exit(f"{path}: not a DDS with a DX10 header")
    height, width, _, _, mips = struct.unpack_from("<5I", data, 12)
    fmt = struct.unpack_from("<I", data, 128)[0]
    levels, at = [], 148
    for k in range(max(1, mips)):
        w, h = max(1, width >> k), max(1, height >> k)
        size = ((w + 3) // 4) * ((h + 3) // 4) * 16
        levels.append(data[at:at + size])
        at += size
    return fmt, width, height, levels


def write_png(path: Path, pixels: np.ndarray) -> None:
    """An 8-bit RGB or grey PNG (stdlib zlib)."""
    h, w = pixels.shape[:2]
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    raw = b"".join(b"\0" + pixels[y].tobytes() for y in range(h))

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    header = struct.pack(">2I5B", w, h, 8, {1: 0, 3: 2, 4: 6}[channels], 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6))
                     + chunk(b"IEND", b""))


class Device:
    """A Vulkan device with BC textures and a compute queue; host-visible memory for everything."""

    def __init__(self) -> None:
        app = vk.VkApplicationInfo(pApplicationName="vulkan_decode", apiVersion=vk.VK_MAKE_VERSION(1, 1, 0))
        self.instance = vk.vkCreateInstance(vk.VkInstanceCreateInfo(pApplicationInfo=app), None)
        for gpu in vk.vkEnumeratePhysicalDevices(self.instance):
            families = vk.vkGetPhysicalDeviceQueueFamilyProperties(gpu)
            compute = [i for i, f in enumerate(families) if f.queueFlags & vk.VK_QUEUE_COMPUTE_BIT]
            if vk.vkGetPhysicalDeviceFeatures(gpu).textureCompressionBC and compute:
                self.gpu, family = gpu, compute[0]
                break
        else:
            sys.exit("no Vulkan device with BC textures and a compute queue")
        queue_info = vk.VkDeviceQueueCreateInfo(queueFamilyIndex=family, queueCount=1, pQueuePriorities=[1.0])
        self.dev = vk.vkCreateDevice(self.gpu, vk.VkDeviceCreateInfo(
            queueCreateInfoCount=1, pQueueCreateInfos=[queue_info],
            pEnabledFeatures=vk.VkPhysicalDeviceFeatures(textureCompressionBC=vk.VK_TRUE)), None)
        self.queue = vk.vkGetDeviceQueue(self.dev, family, 0)
        self.cmd_pool = vk.vkCreateCommandPool(self.dev, vk.VkCommandPoolCreateInfo(queueFamilyIndex=family), None)
        # the whole struct is kept: python-vulkan frees it, and its memoryTypes array, with the object
        self.memory_props = vk.vkGetPhysicalDeviceMemoryProperties(self.gpu)

    def memory(self, requirements, flags: int):
        props = self.memory_props
        index = next((i for i in range(props.memoryTypeCount) if requirements.memoryTypeBits >> i & 1
                      and props.memoryTypes[i].propertyFlags & flags == flags), None)
        if index is None:
            sys.exit("no Vulkan memory type for a buffer or image here")
        return vk.vkAllocateMemory(self.dev, vk.VkMemoryAllocateInfo(allocationSize=requirements.size,
                                                                     memoryTypeIndex=index), None)

    def buffer(self, data: bytes, usage: int = vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT):
        """(buffer, memory, size) holding ``data``, mappable."""
        b = vk.vkCreateBuffer(self.dev, vk.VkBufferCreateInfo(size=len(data), usage=usage), None)
        mem = self.memory(vk.vkGetBufferMemoryRequirements(self.dev, b),
                          vk.VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | vk.VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)
        vk.vkBindBufferMemory(self.dev, b, mem, 0)
        view = vk.vkMapMemory(self.dev, mem, 0, len(data), 0)
        view[:len(data)] = data
        vk.vkUnmapMemory(self.dev, mem)
        return b, mem, len(data)

    def submit(self, record) -> None:
        cmd = vk.vkAllocateCommandBuffers(self.dev, vk.VkCommandBufferAllocateInfo(
            commandPool=self.cmd_pool, level=vk.VK_COMMAND_BUFFER_LEVEL_PRIMARY, commandBufferCount=1))[0]
        vk.vkBeginCommandBuffer(cmd, vk.VkCommandBufferBeginInfo())
        record(cmd)
        vk.vkEndCommandBuffer(cmd)
        vk.vkQueueSubmit(self.queue, 1, [vk.VkSubmitInfo(commandBufferCount=1, pCommandBuffers=[cmd])], None)
        vk.vkQueueWaitIdle(self.queue)
        vk.vkFreeCommandBuffers(self.dev, self.cmd_pool, 1, [cmd])

    def texture(self, path: Path):
        """An image view of a DDS mip chain, uploaded through a staging buffer."""
        fmt, width, height, levels = read_dds(path)
        image = vk.vkCreateImage(self.dev, vk.VkImageCreateInfo(
            imageType=vk.VK_IMAGE_TYPE_2D, format=DXGI_TO_VK[fmt], extent=vk.VkExtent3D(width, height, 1),
            mipLevels=len(levels), arrayLayers=1, samples=vk.VK_SAMPLE_COUNT_1_BIT, tiling=vk.VK_IMAGE_TILING_OPTIMAL,
            usage=vk.VK_IMAGE_USAGE_SAMPLED_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT,
            initialLayout=vk.VK_IMAGE_LAYOUT_UNDEFINED), None)
        vk.vkBindImageMemory(self.dev, image, self.memory(vk.vkGetImageMemoryRequirements(self.dev, image), 0), 0)
        staging, _, _ = self.buffer(b"".join(levels), vk.VK_BUFFER_USAGE_TRANSFER_SRC_BIT)
        whole = vk.VkImageSubresourceRange(aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, levelCount=len(levels), layerCount=1)

        def layout(cmd, old, new, access):
            vk.vkCmdPipelineBarrier(cmd, vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, vk.VK_PIPELINE_STAGE_ALL_COMMANDS_BIT,
                                    0, 0, None, 0, None, 1, [vk.VkImageMemoryBarrier(
                                        dstAccessMask=access, oldLayout=old, newLayout=new, image=image,
                                        srcQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED,
                                        dstQueueFamilyIndex=vk.VK_QUEUE_FAMILY_IGNORED, subresourceRange=whole)])

        def upload(cmd):
            layout(cmd, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                   vk.VK_ACCESS_TRANSFER_WRITE_BIT)
            offsets = np.cumsum([0] + [len(x) for x in levels])
            copies = [vk.VkBufferImageCopy(bufferOffset=int(offsets[k]), imageSubresource=vk.VkImageSubresourceLayers(
                aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, mipLevel=k, layerCount=1),
                imageExtent=vk.VkExtent3D(max(1, width >> k), max(1, height >> k), 1)) for k in range(len(levels))]
            vk.vkCmdCopyBufferToImage(cmd, staging, image, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, len(copies), copies)
            layout(cmd, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                   vk.VK_ACCESS_SHADER_READ_BIT)

        self.submit(upload)
        return vk.vkCreateImageView(self.dev, vk.VkImageViewCreateInfo(
            image=image, viewType=vk.VK_IMAGE_VIEW_TYPE_2D, format=DXGI_TO_VK[fmt], subresourceRange=whole), None)


def read_material(folder: Path) -> dict:
    """material.json of a material folder with a neural part, or exit with one line saying why not."""
    path = folder / "material.json"
    if not path.is_file():
        inside = sorted(p.parent.name for p in (folder / "materials").glob("*/material.json"))
        hint = f": a build; give one of {folder / 'materials'}/{{{','.join(inside)}}}" if inside else ""
        sys.exit(f"{folder}: no material.json{hint}")
    try:
        m = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        sys.exit(f"{path}: not readable as JSON ({e})")
    if m.get("format") != "bcfpipe-material" or "mlp" not in m or not m.get("layers"):
        sys.exit(f"{path}: no neural part (a classic layout's textures are plain DDS files to sample)")
    return m


def decode(folder: Path, spirv: Path, size: int, lod: float, tile: int) -> tuple[dict, np.ndarray]:
    """(material.json, the decoded (size, size, channels) image) at lod ``lod``."""
    m = read_material(folder)
    n_layers = len(m["layers"])
    sampling = m["sampling"]
    wrap = [WRAP[sampling.get(k, sampling.get("addressing"))] for k in ("wrap_s", "wrap_t")]
    neural = [o for o in m["outputs"] if o.get("source") != "classic"]
    kinds = [o["kind"] for o in neural if not o.get("reconstructed")]
    normal = kinds.index("normal") if "normal" in kinds else -1
    stride = len(neural)

    gpu = Device()
    views = [gpu.texture(folder / layer["file"]) for layer in m["layers"]]
    samplers = [vk.vkCreateSampler(gpu.dev, vk.VkSamplerCreateInfo(
        magFilter=vk.VK_FILTER_LINEAR, minFilter=vk.VK_FILTER_LINEAR, mipmapMode=vk.VK_SAMPLER_MIPMAP_MODE_LINEAR,
        addressModeU=wrap[0][1], addressModeV=wrap[1][1], addressModeW=wrap[1][1],
        maxLod=float(layer["mip_count"] - 1)), None) for layer in m["layers"]]
    weights = gpu.buffer((folder / m["mlp"]["weights"]).read_bytes())
    ref = m["reference"]

    storage = vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER
    bindings = [vk.VkDescriptorSetLayoutBinding(binding=b, descriptorType=storage, descriptorCount=1,
                                                stageFlags=vk.VK_SHADER_STAGE_COMPUTE_BIT) for b in range(4)]
    bindings += [vk.VkDescriptorSetLayoutBinding(binding=b, descriptorType=t, descriptorCount=n_layers,
                                                 stageFlags=vk.VK_SHADER_STAGE_COMPUTE_BIT)
                 for b, t in ((4, vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE), (SAMPLER_BINDING, vk.VK_DESCRIPTOR_TYPE_SAMPLER))]
    set_layout = vk.vkCreateDescriptorSetLayout(gpu.dev, vk.VkDescriptorSetLayoutCreateInfo(
        bindingCount=len(bindings), pBindings=bindings), None)
    pipe_layout = vk.vkCreatePipelineLayout(gpu.dev, vk.VkPipelineLayoutCreateInfo(
        setLayoutCount=1, pSetLayouts=[set_layout]), None)
    code = spirv.read_bytes()
    if code[:4] != b"\x03\x02\x23\x07" or len(code) % 4:
        sys.exit(f"{spirv}: not SPIR-V")
    module = vk.vkCreateShaderModule(gpu.dev, vk.VkShaderModuleCreateInfo(codeSize=len(code), pCode=code), None)
    stage = vk.VkPipelineShaderStageCreateInfo(stage=vk.VK_SHADER_STAGE_COMPUTE_BIT, module=module, pName="main")
    pipeline = vk.vkCreateComputePipelines(gpu.dev, None, 1, [vk.VkComputePipelineCreateInfo(
        stage=stage, layout=pipe_layout)], None)[0]
    pool = vk.vkCreateDescriptorPool(gpu.dev, vk.VkDescriptorPoolCreateInfo(maxSets=1, poolSizeCount=3, pPoolSizes=[
        vk.VkDescriptorPoolSize(type=storage, descriptorCount=4),
        vk.VkDescriptorPoolSize(type=vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE, descriptorCount=n_layers),
        vk.VkDescriptorPoolSize(type=vk.VK_DESCRIPTOR_TYPE_SAMPLER, descriptorCount=n_layers)]), None)
    dset = vk.vkAllocateDescriptorSets(gpu.dev, vk.VkDescriptorSetAllocateInfo(
        descriptorPool=pool, descriptorSetCount=1, pSetLayouts=[set_layout]))[0]

    image = np.zeros((size, size, stride), np.float32)
    centres = (np.arange(size) + 0.5) / size
    for y0 in range(0, size, tile):
        for x0 in range(0, size, tile):
            v, u = np.meshgrid(centres[y0:y0 + tile], centres[x0:x0 + tile], indexing="ij")
            count = u.size
            queries = np.stack([u.ravel(), v.ravel(), np.full(count, lod), np.zeros(count)], 1).astype(np.float32)
            # the parameter block (docs/format.md, Other APIs): 48 bytes, then the N lod biases
            params = struct.pack("<IiII2i2f2IfI", m["mlp"]["offset"], normal, count, stride, wrap[0][0], wrap[1][0],
                                 ref["width"], ref["height"], 0, 0, 0.0, 0)
            params += struct.pack(f"<{n_layers}f", *[layer["lod_bias"] for layer in m["layers"]])
            buffers = [weights, gpu.buffer(queries.tobytes()), gpu.buffer(bytes(4 * count * stride)),
                       gpu.buffer(params)]
            writes = [vk.VkWriteDescriptorSet(dstSet=dset, dstBinding=b, descriptorCount=1, descriptorType=storage,
                                              pBufferInfo=[vk.VkDescriptorBufferInfo(buffer=buf, range=n)])
                      for b, (buf, _, n) in enumerate(buffers)]
            writes.append(vk.VkWriteDescriptorSet(dstSet=dset, dstBinding=4, descriptorCount=n_layers,
                                                  descriptorType=vk.VK_DESCRIPTOR_TYPE_SAMPLED_IMAGE, pImageInfo=[
                vk.VkDescriptorImageInfo(imageView=view, imageLayout=vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL)
                for view in views]))
            writes.append(vk.VkWriteDescriptorSet(dstSet=dset, dstBinding=SAMPLER_BINDING, descriptorCount=n_layers,
                                                  descriptorType=vk.VK_DESCRIPTOR_TYPE_SAMPLER,
                                                  pImageInfo=[vk.VkDescriptorImageInfo(sampler=s) for s in samplers]))
            vk.vkUpdateDescriptorSets(gpu.dev, len(writes), writes, 0, None)

            def dispatch(cmd):
                vk.vkCmdBindPipeline(cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, pipeline)
                vk.vkCmdBindDescriptorSets(cmd, vk.VK_PIPELINE_BIND_POINT_COMPUTE, pipe_layout, 0, 1, [dset], 0, None)
                vk.vkCmdDispatch(cmd, (count + 63) // 64, 1, 1)

            gpu.submit(dispatch)
            out_mem = buffers[2][1]
            view = vk.vkMapMemory(gpu.dev, out_mem, 0, 4 * count * stride, 0)
            values = np.frombuffer(bytes(view[:4 * count * stride]), np.float32).reshape(u.shape + (stride,))
            vk.vkUnmapMemory(gpu.dev, out_mem)
            image[y0:y0 + tile, x0:x0 + tile] = values
            for buf, mem, _ in buffers[1:]:
                vk.vkDestroyBuffer(gpu.dev, buf, None)
                vk.vkFreeMemory(gpu.dev, mem, None)
    if np.isnan(image).any():
        sys.exit(f"{folder}: the kernel refused the weight record (NaN): another layer count or shape?")
    return m, image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("material", type=Path, help="a material folder of a build (material.json, T*.dds, weights)")
    ap.add_argument("-o", "--output", type=Path, required=True, help="folder for the PNGs")
    ap.add_argument("--lod", type=float, default=0.0, help="s, in the reference's mip units (default 0)")
    ap.add_argument("--size", type=int, default=512, help="image width and height (default 512)")
    ap.add_argument("--tile", type=int, default=256, help="texels per tile side, one dispatch each (default 256)")
    ap.add_argument("--spirv", type=Path, default=None,
                    help="the kernel (default: the installed bcfpipe's decoders/bcf_decode_N.spv)")
    args = ap.parse_args()
    n_layers = len(read_material(args.material)["layers"])
    spirv = args.spirv
    if spirv is None:  # where the package ships it; an engine keeps its own copy
        import importlib.util
        spec = importlib.util.find_spec("bcfpipe")
        spirv = Path(spec.origin).parent / "decoders" / f"bcf_decode_{n_layers}.spv"
    if not spirv.is_file():
        sys.exit(f"{spirv}: no such kernel (pass --spirv bcfpipe/decoders/bcf_decode_{n_layers}.spv)")
    m, image = decode(args.material, spirv, args.size, args.lod, args.tile)
    args.output.mkdir(parents=True, exist_ok=True)
    neural = [o for o in m["outputs"] if o.get("source") != "classic"]
    for semantic in dict.fromkeys(o["semantic"] for o in neural):
        idx = [i for i, o in enumerate(neural) if o["semantic"] == semantic]
        values = image[..., idx] * [neural[i]["value_scale"] for i in idx] + [neural[i]["value_bias"] for i in idx]
        if neural[idx[0]]["kind"] == "normal":
            values = values * 0.5 + 0.5
        if values.shape[-1] == 2:
            values = np.concatenate([values, np.zeros_like(values[..., :1])], -1)
        pixels = np.round(np.clip(values, 0, 1) * 255).astype(np.uint8)
        write_png(args.output / f"{semantic}.png", pixels[..., 0] if pixels.shape[-1] == 1 else pixels)
        print(args.output / f"{semantic}.png")


if __name__ == "__main__":
    main()
