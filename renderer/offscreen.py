"""Offscreen rendering with dynamic rendering: a colour target (R8G8B8A8_SRGB), a depth buffer,
readback to numpy.

* Materials live in a storage buffer; base-colour textures in a fixed-size array of 16
  combined image samplers (lavapipe has no descriptor indexing), indexed per draw through a
  push constant. Models with more than 16 textures get one descriptor set per 16.
* Opaque and MASK draws first, then BLEND draws back to front with alpha blending (depth test
  on, depth write off). ``doubleSided`` disables culling, otherwise back faces are culled.
* ``mode="silhouette"`` draws every triangle in white with the materials' culling (no
  blending, no alpha discard): what is visible of the geometry, so holes and flipped
  windings show. ``mode="coverage"`` draws every triangle without culling. ``mode="facing"``
  draws every triangle without culling, red 255 where the nearest surface faces the camera
  (or is double-sided) and about 188 (0.5 in sRGB) where a back face is nearest: coverage and
  winding from one render (see :func:`renderer.compare.front`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from assetpipe.core.errors import RenderError

from .camera import Camera
from .cull import CULL_MIN_TRIANGLES, Projector
from .cull import cull as cull_draws
from .loader import RenderModel, Texture
from .results import MAX_RENDER_SIZE
from .shaders import compile_glsl, shader_path
from .vk_context import Buffer, Image, VkContext

TEXTURE_SLOTS = 16
MATERIAL_FLOATS = 16  # the shader's Material: baseColor, params, roles, uvSets (four vec4, std430)
VERTEX_STRIDE = 44  # position (3) + uv0 (2) + colour (4) + uv1 (2) float32
PUSH_SIZE = 112     # mat4 + vec4 + vec4 + ivec4
COLOR_FORMAT_NAME = "VK_FORMAT_R8G8B8A8_SRGB"
DEPTH_FORMAT_NAME = "VK_FORMAT_D32_SFLOAT"
LIGHT_DIR = np.array([0.4, 0.8, 0.6])  # towards the light, camera-relative (x right, y up, z back)

VK_FORMAT_BC5_UNORM_BLOCK, VK_FORMAT_EAC_R11G11_UNORM_BLOCK = 141, 155  # two-channel normals: z rebuilt
_MODE_CODE = {"facing": 2, "shaded+facing": 3}  # the fragment shader's pc.sel.z
_WRAP = {10497: "VK_SAMPLER_ADDRESS_MODE_REPEAT", 33071: "VK_SAMPLER_ADDRESS_MODE_CLAMP_TO_EDGE",
         33648: "VK_SAMPLER_ADDRESS_MODE_MIRRORED_REPEAT"}


@dataclass
class Draw:
    """One indexed draw of one mesh at one LOD."""

    mesh: int
    material: int
    first_index: int
    index_count: int
    vertex_offset: int
    blended: bool
    double_sided: bool
    tex_set: int
    tex_slot: int
    center: np.ndarray


@dataclass
class GpuModel:
    """A :class:`RenderModel` uploaded: buffers, textures, samplers, descriptor sets."""

    model: RenderModel
    vertex_buffer: Buffer
    index_buffer: Buffer
    material_buffer: Buffer
    images: list[Image]
    samplers: list[Any]
    descriptor_pool: Any
    descriptor_sets: list[Any]
    texture_slots: list[tuple[int, int]]  # per material: (set, slot); slot 0 of each set is white
    upload_seconds: float = 0.0
    destroyed: bool = field(default=False)
    plain: bool = False  # no texture in any role and white vertex colours: shaded through the PLAIN shaders
    # culling (renderer/cull.py): the kept indices go to ``cull_buffer`` (host-visible, rewritten
    # before each render that culls)
    cull_buffer: Buffer | None = None
    projector: Projector | None = None


class Renderer:
    """Pipelines and render targets on a :class:`VkContext`; draws :class:`GpuModel` s."""

    def __init__(self, ctx: VkContext, width: int = 256, height: int = 256,
                 shader_cache: Path | None = None) -> None:
        self.ctx = ctx
        self.vk = vk = ctx.vk
        self.color_format = getattr(vk, COLOR_FORMAT_NAME)
        self.depth_format = getattr(vk, DEPTH_FORMAT_NAME)
        self.width = self.height = 0
        self.color: Image | None = None
        self.depth: Image | None = None
        self.readback: Buffer | None = None
        self.timings: dict[str, float] = {"compile": 0.0, "upload": 0.0, "render": 0.0}
        self.cull = True  # leave out triangles that cover no pixel centre (renderer/cull.py; same pictures)
        t0 = time.perf_counter()
        self._vert = self._module(compile_glsl(shader_path("mesh.vert"), shader_cache))
        self._frag = self._module(compile_glsl(shader_path("mesh.frag"), shader_cache))
        self._lean_vert = self._module(compile_glsl(shader_path("lean.vert"), shader_cache))
        self._lean_frag = self._module(compile_glsl(shader_path("lean.frag"), shader_cache))
        self._plain_vert = self._module(compile_glsl(shader_path("mesh.vert"), shader_cache, ("PLAIN",)))
        self._plain_frag = self._module(compile_glsl(shader_path("mesh.frag"), shader_cache, ("PLAIN",)))
        self.timings["compile"] = time.perf_counter() - t0
        self._make_layouts()
        self._pipelines: dict[tuple[bool, bool], Any] = {}
        for cull in (False, True):
            for blend in (False, True):
                self._pipelines[(cull, blend)] = self._make_pipeline(cull, blend)
        # coverage, silhouette and facing: position only, no varyings (lean.vert/lean.frag). lavapipe
        # sets up every triangle's attribute planes: MetalRoughSpheresNoTextures' facing renders of
        # 1.04M triangles cost about half as much without them (see docs/VALIDATE.md, "Speed")
        self._lean = {cull: self._make_pipeline(cull, False, variant="lean") for cull in (False, True)}
        # shaded renders of a model without textures and with white vertex colours: mesh.vert/.frag
        # compiled with PLAIN, the position the only varying (GpuModel.plain)
        self._plain = {(cull, blend): self._make_pipeline(cull, blend, variant="plain")
                       for cull in (False, True) for blend in (False, True)}
        self.white = self._upload_texture(Texture("white", [np.full((1, 1, 4), 255, np.uint8)], 37))
        self.white_sampler = self._make_sampler({}, 1)
        self.resize(width, height)

    # -------------------------------------------------------------------- pipelines
    def _module(self, spirv: bytes) -> Any:
        vk = self.vk
        return vk.vkCreateShaderModule(self.ctx.device, vk.VkShaderModuleCreateInfo(
            codeSize=len(spirv), pCode=spirv), None)

    def _make_layouts(self) -> None:
        vk = self.vk
        frag = vk.VK_SHADER_STAGE_FRAGMENT_BIT
        bindings = [
            vk.VkDescriptorSetLayoutBinding(binding=0, descriptorType=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                                            descriptorCount=1, stageFlags=frag),
            vk.VkDescriptorSetLayoutBinding(binding=1,
                                            descriptorType=vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER,
                                            descriptorCount=TEXTURE_SLOTS, stageFlags=frag),
        ]
        self.set_layout = vk.vkCreateDescriptorSetLayout(self.ctx.device, vk.VkDescriptorSetLayoutCreateInfo(
            bindingCount=len(bindings), pBindings=bindings), None)
        push = vk.VkPushConstantRange(stageFlags=vk.VK_SHADER_STAGE_VERTEX_BIT | frag, offset=0, size=PUSH_SIZE)
        self.pipeline_layout = vk.vkCreatePipelineLayout(self.ctx.device, vk.VkPipelineLayoutCreateInfo(
            setLayoutCount=1, pSetLayouts=[self.set_layout], pushConstantRangeCount=1,
            pPushConstantRanges=[push]), None)

    def _make_pipeline(self, cull: bool, blend: bool, variant: str = "full") -> Any:
        vk = self.vk
        vert, frag = {"full": (self._vert, self._frag), "lean": (self._lean_vert, self._lean_frag),
                      "plain": (self._plain_vert, self._plain_frag)}[variant]
        stages = [
            vk.VkPipelineShaderStageCreateInfo(stage=vk.VK_SHADER_STAGE_VERTEX_BIT, module=vert, pName="main"),
            vk.VkPipelineShaderStageCreateInfo(stage=vk.VK_SHADER_STAGE_FRAGMENT_BIT, module=frag, pName="main"),
        ]
        binding = vk.VkVertexInputBindingDescription(binding=0, stride=VERTEX_STRIDE,
                                                     inputRate=vk.VK_VERTEX_INPUT_RATE_VERTEX)
        attrs = [
            vk.VkVertexInputAttributeDescription(location=0, binding=0, format=vk.VK_FORMAT_R32G32B32_SFLOAT,
                                                 offset=0),
            vk.VkVertexInputAttributeDescription(location=1, binding=0, format=vk.VK_FORMAT_R32G32_SFLOAT,
                                                 offset=12),
            vk.VkVertexInputAttributeDescription(location=2, binding=0, format=vk.VK_FORMAT_R32G32B32A32_SFLOAT,
                                                 offset=20),
            vk.VkVertexInputAttributeDescription(location=3, binding=0, format=vk.VK_FORMAT_R32G32_SFLOAT,
                                                 offset=36),
        ]
        if variant != "full":
            attrs = attrs[:1]
        vertex_input = vk.VkPipelineVertexInputStateCreateInfo(
            vertexBindingDescriptionCount=1, pVertexBindingDescriptions=[binding],
            vertexAttributeDescriptionCount=len(attrs), pVertexAttributeDescriptions=attrs)
        assembly = vk.VkPipelineInputAssemblyStateCreateInfo(topology=vk.VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST)
        viewport = vk.VkPipelineViewportStateCreateInfo(viewportCount=1, scissorCount=1)
        raster = vk.VkPipelineRasterizationStateCreateInfo(
            polygonMode=vk.VK_POLYGON_MODE_FILL,
            cullMode=vk.VK_CULL_MODE_BACK_BIT if cull else vk.VK_CULL_MODE_NONE,
            frontFace=vk.VK_FRONT_FACE_COUNTER_CLOCKWISE, lineWidth=1.0)
        multisample = vk.VkPipelineMultisampleStateCreateInfo(rasterizationSamples=vk.VK_SAMPLE_COUNT_1_BIT)
        depth = vk.VkPipelineDepthStencilStateCreateInfo(
            depthTestEnable=vk.VK_TRUE, depthWriteEnable=vk.VK_FALSE if blend else vk.VK_TRUE,
            depthCompareOp=vk.VK_COMPARE_OP_LESS_OR_EQUAL)
        all_rgba = (vk.VK_COLOR_COMPONENT_R_BIT | vk.VK_COLOR_COMPONENT_G_BIT | vk.VK_COLOR_COMPONENT_B_BIT
                    | vk.VK_COLOR_COMPONENT_A_BIT)
        if blend:
            attachment = vk.VkPipelineColorBlendAttachmentState(
                blendEnable=vk.VK_TRUE, srcColorBlendFactor=vk.VK_BLEND_FACTOR_SRC_ALPHA,
                dstColorBlendFactor=vk.VK_BLEND_FACTOR_ONE_MINUS_SRC_ALPHA, colorBlendOp=vk.VK_BLEND_OP_ADD,
                srcAlphaBlendFactor=vk.VK_BLEND_FACTOR_ONE,
                dstAlphaBlendFactor=vk.VK_BLEND_FACTOR_ONE_MINUS_SRC_ALPHA, alphaBlendOp=vk.VK_BLEND_OP_ADD,
                colorWriteMask=all_rgba)
        else:
            attachment = vk.VkPipelineColorBlendAttachmentState(blendEnable=vk.VK_FALSE, colorWriteMask=all_rgba)
        blend_state = vk.VkPipelineColorBlendStateCreateInfo(attachmentCount=1, pAttachments=[attachment])
        dynamic = vk.VkPipelineDynamicStateCreateInfo(
            dynamicStateCount=2, pDynamicStates=[vk.VK_DYNAMIC_STATE_VIEWPORT, vk.VK_DYNAMIC_STATE_SCISSOR])
        rendering = vk.VkPipelineRenderingCreateInfo(colorAttachmentCount=1,
                                                     pColorAttachmentFormats=[self.color_format],
                                                     depthAttachmentFormat=self.depth_format)
        info = vk.VkGraphicsPipelineCreateInfo(
            pNext=rendering, stageCount=2, pStages=stages, pVertexInputState=vertex_input,
            pInputAssemblyState=assembly, pViewportState=viewport, pRasterizationState=raster,
            pMultisampleState=multisample, pDepthStencilState=depth, pColorBlendState=blend_state,
            pDynamicState=dynamic, layout=self.pipeline_layout)
        return vk.vkCreateGraphicsPipelines(self.ctx.device, None, 1, [info], None)[0]

    # ----------------------------------------------------------------------- targets
    def resize(self, width: int, height: int) -> None:
        """(Re)create the colour and depth targets and the readback buffer at width x height."""
        if (width, height) == (self.width, self.height):
            return
        if not (0 < width <= MAX_RENDER_SIZE and 0 < height <= MAX_RENDER_SIZE):
            raise RenderError(f"render size {width}x{height} is out of range")
        self._destroy_targets()
        vk = self.vk
        self.width, self.height = int(width), int(height)
        self.color = self.ctx.create_image(width, height, self.color_format,
                                           vk.VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT
                                           | vk.VK_IMAGE_USAGE_TRANSFER_SRC_BIT)
        self.depth = self.ctx.create_image(width, height, self.depth_format,
                                           vk.VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT,
                                           aspect=vk.VK_IMAGE_ASPECT_DEPTH_BIT)
        self.readback = self.ctx.create_buffer(width * height * 4, vk.VK_BUFFER_USAGE_TRANSFER_DST_BIT)

    def _destroy_targets(self) -> None:
        for res in (self.color, self.depth, self.readback):
            if res is not None:
                res.destroy()
        self.color = self.depth = self.readback = None

    # ---------------------------------------------------------------------- textures
    def _make_sampler(self, sampler: dict[str, Any], levels: int) -> Any:
        vk = self.vk
        mag = sampler.get("magFilter")
        mn = sampler.get("minFilter")
        nearest_min = mn in (9728, 9984, 9986)
        mip_nearest = mn in (9984, 9985)
        no_mips = mn in (9728, 9729)
        return vk.vkCreateSampler(self.ctx.device, vk.VkSamplerCreateInfo(
            magFilter=vk.VK_FILTER_NEAREST if mag == 9728 else vk.VK_FILTER_LINEAR,
            minFilter=vk.VK_FILTER_NEAREST if nearest_min else vk.VK_FILTER_LINEAR,
            mipmapMode=vk.VK_SAMPLER_MIPMAP_MODE_NEAREST if mip_nearest else vk.VK_SAMPLER_MIPMAP_MODE_LINEAR,
            addressModeU=getattr(vk, _WRAP.get(sampler.get("wrapS", 10497), _WRAP[10497])),
            addressModeV=getattr(vk, _WRAP.get(sampler.get("wrapT", 10497), _WRAP[10497])),
            addressModeW=vk.VK_SAMPLER_ADDRESS_MODE_REPEAT,
            minLod=0.0, maxLod=0.25 if no_mips else float(levels),
            borderColor=vk.VK_BORDER_COLOR_FLOAT_OPAQUE_WHITE), None)

    def _upload_texture(self, tex: Texture, notes: list[str] | None = None) -> Image:
        """An image with every level of ``tex`` copied in as stored, ready for sampling. A block
        format the device cannot sample is decoded on the CPU first (said in ``notes``)."""
        vk, ctx = self.vk, self.ctx
        if tex.size is not None and not ctx.can_sample(tex.vk_format):
            tex = _decoded(tex, ctx.info.name, notes)
        levels = tex.levels
        image = ctx.create_image(tex.width, tex.height, tex.vk_format,
                                 vk.VK_IMAGE_USAGE_SAMPLED_BIT | vk.VK_IMAGE_USAGE_TRANSFER_DST_BIT,
                                 levels=len(levels))
        sizes = [lv.nbytes for lv in levels]
        staging = ctx.create_buffer(sum(sizes), vk.VK_BUFFER_USAGE_TRANSFER_SRC_BIT)
        staging.write(np.concatenate([lv.reshape(-1) for lv in levels]))
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
        regions = [vk.VkBufferImageCopy(
            bufferOffset=int(off), bufferRowLength=0, bufferImageHeight=0,
            imageSubresource=vk.VkImageSubresourceLayers(aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, mipLevel=i,
                                                         baseArrayLayer=0, layerCount=1),
            imageOffset=vk.VkOffset3D(x=0, y=0, z=0),
            imageExtent=vk.VkExtent3D(width=tex.level_size(i)[0], height=tex.level_size(i)[1], depth=1))
            for i, (lv, off) in enumerate(zip(levels, offsets))]

        def record(cmd: Any) -> None:
            ctx.image_barrier(cmd, image, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                              vk.VK_PIPELINE_STAGE_2_NONE, vk.VK_ACCESS_2_NONE,
                              vk.VK_PIPELINE_STAGE_2_COPY_BIT, vk.VK_ACCESS_2_TRANSFER_WRITE_BIT)
            vk.vkCmdCopyBufferToImage(cmd, staging.handle, image.handle, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                                      len(regions), regions)
            ctx.image_barrier(cmd, image, vk.VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                              vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL,
                              vk.VK_PIPELINE_STAGE_2_COPY_BIT, vk.VK_ACCESS_2_TRANSFER_WRITE_BIT,
                              vk.VK_PIPELINE_STAGE_2_FRAGMENT_SHADER_BIT, vk.VK_ACCESS_2_SHADER_SAMPLED_READ_BIT)

        try:
            ctx.submit(record)
        finally:
            staging.destroy()
        return image

    # ------------------------------------------------------------------------ models
    def upload(self, model: RenderModel, cams: list | None = None) -> GpuModel:
        """Upload vertices, indices, materials and textures of ``model``.

        ``cams``: the only cameras its shaded renders will use (LOD 0). Each texture is then
        uploaded from the first mip level those renders can sample
        (:mod:`renderer.texture_levels`; the pictures are the same); None: every level."""
        vk, ctx = self.vk, self.ctx
        t0 = time.perf_counter()
        first_level = _first_levels(model, cams) if cams else {}
        uv1 = model.uvs1 if model.uvs1 is not None else np.zeros((len(model.positions), 2), np.float32)
        verts = np.concatenate([model.positions, model.uvs, model.colors, uv1], axis=1).astype(np.float32)
        vb = ctx.create_buffer(verts.nbytes, vk.VK_BUFFER_USAGE_VERTEX_BUFFER_BIT)
        vb.write(verts)
        ib = ctx.create_buffer(model.indices.nbytes, vk.VK_BUFFER_USAGE_INDEX_BUFFER_BIT)
        ib.write(model.indices.astype(np.uint32))
        mat_rows = np.zeros((max(len(model.materials), 1), MATERIAL_FLOATS), np.float32)
        mat_rows[:, :4] = 1.0
        for i, m in enumerate(model.materials):
            mat_rows[i, :4] = m.base_color
            mat_rows[i, 4] = m.alpha_cutoff
            mat_rows[i, 5] = {"OPAQUE": 0, "MASK": 1, "BLEND": 2}.get(m.alpha_mode, 0)
        mb = ctx.create_buffer(mat_rows.nbytes, vk.VK_BUFFER_USAGE_STORAGE_BUFFER_BIT)

        images: list[Image] = []  # each uploaded once (see image_key)
        samplers: list[Any] = []
        pairs: list[tuple[Image, Any]] = []  # (image, sampler) of each combined-image-sampler slot used
        image_of: dict[tuple, Image] = {}
        sampler_of: dict[tuple, Any] = {}
        slots: list[tuple[int, int]] = []
        per_set = TEXTURE_SLOTS - 1  # slot 0 of every set is the white texture
        by_set: list[list[int]] = [[]]  # per descriptor set: indices into pairs, slot 1 onwards
        uploaded: dict[int, int] = {}  # id(Texture) -> its index in pairs

        for i, m in enumerate(model.materials):
            roles = (m.texture, m.normal_texture, m.metallic_roughness_texture, m.occlusion_texture,
                     m.emissive_texture)
            texs = [t for t in roles if t is not None]
            if len(by_set[-1]) + len(texs) > per_set:  # a material's textures share one set
                by_set.append([])
            placed = []
            for t in texs:
                k = uploaded.get(id(t))
                if k is None or k not in by_set[-1]:  # the same Texture in two roles: one image
                    if k is None:
                        ik, sk = image_key(t), (repr(sorted(t.sampler.items())), len(t.levels))
                        skip = first_level.get(ik, 0)
                        sk = (sk[0], len(t.levels) - skip)
                        if ik not in image_of:
                            image_of[ik] = self._upload_texture(_from_level(t, skip), model.notes)
                            images.append(image_of[ik])
                        if sk not in sampler_of:
                            sampler_of[sk] = self._make_sampler(t.sampler, len(t.levels) - skip)
                            samplers.append(sampler_of[sk])
                        pairs.append((image_of[ik], sampler_of[sk]))
                        k = uploaded[id(t)] = len(pairs) - 1
                    by_set[-1].append(k)
                placed.append(by_set[-1].index(k) + 1)
            slot_of = dict(zip([k for k, t in enumerate(roles) if t is not None], placed))
            s_idx = len(by_set) - 1
            base_slot = slot_of.get(0, 0)
            slots.append((s_idx if texs else 0, base_slot))
            if m.normal_texture is not None:  # the shader reads the normal map's slot and channel count
                mat_rows[i, 6] = slot_of[1]
                fmt = m.normal_texture.vk_format
                two = fmt in (VK_FORMAT_BC5_UNORM_BLOCK, VK_FORMAT_EAC_R11G11_UNORM_BLOCK)
                mat_rows[i, 7] = 2.0 if two else 1.0
            for k in (2, 3, 4):  # metallic-roughness, occlusion, emissive slots (0: not drawn)
                mat_rows[i, 6 + k] = slot_of.get(k, 0)
            mat_rows[i, 12:16] = m.role_uv  # the UV set (0 uv0, 1 uv1) of normal, m-r, occlusion, emissive
        mb.write(mat_rows)
        n_sets = len(by_set)
        pool = vk.vkCreateDescriptorPool(ctx.device, vk.VkDescriptorPoolCreateInfo(
            maxSets=n_sets, poolSizeCount=2, pPoolSizes=[
                vk.VkDescriptorPoolSize(type=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, descriptorCount=n_sets),
                vk.VkDescriptorPoolSize(type=vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER,
                                        descriptorCount=n_sets * TEXTURE_SLOTS)]), None)
        sets = vk.vkAllocateDescriptorSets(ctx.device, vk.VkDescriptorSetAllocateInfo(
            descriptorPool=pool, descriptorSetCount=n_sets, pSetLayouts=[self.set_layout] * n_sets))
        sets = list(sets)
        writes = []
        keep = []
        for s, dset in enumerate(sets):
            infos = []
            for slot in range(TEXTURE_SLOTS):
                if 0 < slot <= len(by_set[s]):
                    img, smp = pairs[by_set[s][slot - 1]]
                else:
                    img, smp = self.white, self.white_sampler
                infos.append(vk.VkDescriptorImageInfo(sampler=smp, imageView=img.view,
                                                      imageLayout=vk.VK_IMAGE_LAYOUT_SHADER_READ_ONLY_OPTIMAL))
            buf_info = vk.VkDescriptorBufferInfo(buffer=mb.handle, offset=0, range=mb.size)
            keep.append((infos, buf_info))
            writes.append(vk.VkWriteDescriptorSet(dstSet=dset, dstBinding=0, dstArrayElement=0, descriptorCount=1,
                                                  descriptorType=vk.VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                                                  pBufferInfo=[buf_info]))
            writes.append(vk.VkWriteDescriptorSet(dstSet=dset, dstBinding=1, dstArrayElement=0,
                                                  descriptorCount=TEXTURE_SLOTS,
                                                  descriptorType=vk.VK_DESCRIPTOR_TYPE_COMBINED_IMAGE_SAMPLER,
                                                  pImageInfo=infos))
        vk.vkUpdateDescriptorSets(ctx.device, len(writes), writes, 0, None)
        dt = time.perf_counter() - t0
        self.timings["upload"] += dt
        plain = not images and bool(np.all(model.colors == 1.0))
        return GpuModel(model, vb, ib, mb, images, samplers, pool, sets, slots, upload_seconds=dt, plain=plain)

    def release(self, gpu: GpuModel) -> None:
        """Destroy everything :meth:`upload` created for ``gpu``."""
        if gpu.destroyed:
            return
        vk = self.vk
        self.ctx.wait_idle()
        vk.vkDestroyDescriptorPool(self.ctx.device, gpu.descriptor_pool, None)
        for s in gpu.samplers:
            vk.vkDestroySampler(self.ctx.device, s, None)
        for img in gpu.images:
            img.destroy()
        for b in (gpu.vertex_buffer, gpu.index_buffer, gpu.material_buffer, gpu.cull_buffer):
            if b is not None:
                b.destroy()
        gpu.destroyed = True

    def draws(self, gpu: GpuModel, lod: int = 0, meshes: list[int] | None = None) -> list[Draw]:
        """The draws of ``gpu`` at LOD ``lod`` (a mesh with fewer levels draws its coarsest)."""
        out: list[Draw] = []
        model = gpu.model
        for i, mesh in enumerate(model.meshes):
            if (meshes is not None and i not in meshes) or not mesh.lods:
                continue
            level = mesh.lods[min(lod, len(mesh.lods) - 1)]
            if level.index_count == 0:
                continue
            mat = model.materials[mesh.material]
            tex_set, tex_slot = gpu.texture_slots[mesh.material]
            out.append(Draw(i, mesh.material, level.first_index, level.index_count, mesh.vertex_base,
                            mat.blended, mat.double_sided, tex_set, tex_slot, mesh.center))
        return out

    # ------------------------------------------------------------------------ render
    def render(self, gpu: GpuModel, camera: Camera, mode: str = "shaded", lod: int = 0,
               meshes: list[int] | None = None) -> np.ndarray:
        """Draw ``gpu`` seen by ``camera``; returns the colour target as (H, W, 4) uint8 (sRGB).

        The background is transparent black (alpha 0): alpha > 0 is the coverage.
        """
        if mode not in ("shaded", "silhouette", "coverage", "facing", "shaded+facing"):
            raise ValueError(f"unknown render mode {mode!r}")
        t0 = time.perf_counter()
        self.resize(camera.width, camera.height)
        vk, ctx = self.vk, self.ctx
        silhouette = mode not in ("shaded", "shaded+facing")
        draws = self.draws(gpu, lod, meshes)
        draws, index_buffer = self._culled(gpu, draws, camera)
        eye = np.asarray(camera.eye, np.float64)
        opaque = [d for d in draws if silhouette or not d.blended]
        blended = sorted((d for d in draws if not silhouette and d.blended),
                         key=lambda d: -float(np.linalg.norm(d.center - eye)))
        view_inv = np.linalg.inv(camera.view)
        light = view_inv[:3, :3] @ (LIGHT_DIR / np.linalg.norm(LIGHT_DIR))
        floats = np.zeros(24, np.float32)
        floats[:16] = camera.view_proj.T.reshape(-1)  # column-major for GLSL
        floats[16:19] = eye
        floats[20:23] = light
        color, depth, readback = self.color, self.depth, self.readback
        assert color is not None and depth is not None and readback is not None
        w, h = self.width, self.height

        def record(cmd: Any) -> None:
            ctx.image_barrier(cmd, color, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                              vk.VK_PIPELINE_STAGE_2_COPY_BIT, vk.VK_ACCESS_2_NONE,
                              vk.VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                              vk.VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT | vk.VK_ACCESS_2_COLOR_ATTACHMENT_READ_BIT)
            tests = vk.VK_PIPELINE_STAGE_2_EARLY_FRAGMENT_TESTS_BIT | vk.VK_PIPELINE_STAGE_2_LATE_FRAGMENT_TESTS_BIT
            ctx.image_barrier(cmd, depth, vk.VK_IMAGE_LAYOUT_UNDEFINED, vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
                              tests, vk.VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT, tests,
                              vk.VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_READ_BIT
                              | vk.VK_ACCESS_2_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT)
            area = vk.VkRect2D(offset=vk.VkOffset2D(x=0, y=0), extent=vk.VkExtent2D(width=w, height=h))
            color_att = vk.VkRenderingAttachmentInfo(
                imageView=color.view, imageLayout=vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR, storeOp=vk.VK_ATTACHMENT_STORE_OP_STORE,
                clearValue=vk.VkClearValue(color=vk.VkClearColorValue(float32=[0.0, 0.0, 0.0, 0.0])))
            depth_att = vk.VkRenderingAttachmentInfo(
                imageView=depth.view, imageLayout=vk.VK_IMAGE_LAYOUT_DEPTH_ATTACHMENT_OPTIMAL,
                loadOp=vk.VK_ATTACHMENT_LOAD_OP_CLEAR, storeOp=vk.VK_ATTACHMENT_STORE_OP_DONT_CARE,
                clearValue=vk.VkClearValue(depthStencil=vk.VkClearDepthStencilValue(depth=1.0, stencil=0)))
            vk.vkCmdBeginRendering(cmd, vk.VkRenderingInfo(renderArea=area, layerCount=1, colorAttachmentCount=1,
                                                           pColorAttachments=[color_att],
                                                           pDepthAttachment=depth_att))
            vk.vkCmdSetViewport(cmd, 0, 1, [vk.VkViewport(x=0, y=0, width=w, height=h, minDepth=0.0,
                                                          maxDepth=1.0)])
            vk.vkCmdSetScissor(cmd, 0, 1, [area])
            if draws:
                vk.vkCmdBindVertexBuffers(cmd, 0, 1, [gpu.vertex_buffer.handle], [0])
                vk.vkCmdBindIndexBuffer(cmd, index_buffer.handle, 0, vk.VK_INDEX_TYPE_UINT32)
            bound_pipe = bound_set = pushed = None
            ints = np.zeros(4, np.int32)
            lean = mode in ("coverage", "facing", "silhouette")  # the lean pipelines (lean.vert/lean.frag)
            for d in opaque + blended:
                if mode in ("coverage", "facing"):
                    pipe = self._lean[False]
                elif mode == "silhouette":
                    pipe = self._lean[not d.double_sided]
                elif mode == "shaded+facing":
                    pipe = (self._plain if gpu.plain else self._pipelines)[(False, False)]
                else:
                    pipe = (self._plain if gpu.plain else self._pipelines)[(not d.double_sided, d.blended)]
                if pipe is not bound_pipe:
                    vk.vkCmdBindPipeline(cmd, vk.VK_PIPELINE_BIND_POINT_GRAPHICS, pipe)
                    bound_pipe = pipe
                dset = gpu.descriptor_sets[d.tex_set]
                if dset is not bound_set:
                    vk.vkCmdBindDescriptorSets(cmd, vk.VK_PIPELINE_BIND_POINT_GRAPHICS, self.pipeline_layout,
                                               0, 1, [dset], 0, None)
                    bound_set = dset
                code = _MODE_CODE.get(mode, 1 if silhouette else 0)
                # lean.frag reads only the mode and double-sidedness: a draw there pushes constants only
                # when those change (they persist across draws and pipelines of this one layout)
                key = (0, 0, code, int(d.double_sided)) if lean else (d.material, d.tex_slot, code,
                                                                      int(d.double_sided))
                if key != pushed:
                    ints[:] = key
                    data = np.concatenate([floats.view(np.uint8), ints.view(np.uint8)])
                    vk.vkCmdPushConstants(cmd, self.pipeline_layout,
                                          vk.VK_SHADER_STAGE_VERTEX_BIT | vk.VK_SHADER_STAGE_FRAGMENT_BIT,
                                          0, PUSH_SIZE, vk.ffi.from_buffer(data))
                    pushed = key
                vk.vkCmdDrawIndexed(cmd, d.index_count, 1, d.first_index, d.vertex_offset, 0)
            vk.vkCmdEndRendering(cmd)
            ctx.image_barrier(cmd, color, vk.VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                              vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                              vk.VK_PIPELINE_STAGE_2_COLOR_ATTACHMENT_OUTPUT_BIT,
                              vk.VK_ACCESS_2_COLOR_ATTACHMENT_WRITE_BIT,
                              vk.VK_PIPELINE_STAGE_2_COPY_BIT, vk.VK_ACCESS_2_TRANSFER_READ_BIT)
            region = vk.VkBufferImageCopy(
                bufferOffset=0, bufferRowLength=0, bufferImageHeight=0,
                imageSubresource=vk.VkImageSubresourceLayers(aspectMask=vk.VK_IMAGE_ASPECT_COLOR_BIT, mipLevel=0,
                                                             baseArrayLayer=0, layerCount=1),
                imageOffset=vk.VkOffset3D(x=0, y=0, z=0), imageExtent=vk.VkExtent3D(width=w, height=h, depth=1))
            vk.vkCmdCopyImageToBuffer(cmd, color.handle, vk.VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                                      readback.handle, 1, [region])
            ctx.memory_barrier(cmd, vk.VK_PIPELINE_STAGE_2_COPY_BIT, vk.VK_ACCESS_2_TRANSFER_WRITE_BIT,
                               vk.VK_PIPELINE_STAGE_2_HOST_BIT, vk.VK_ACCESS_2_HOST_READ_BIT)

        ctx.submit(record)
        out = readback.read(w * h * 4).reshape(h, w, 4)
        self.timings["render"] += time.perf_counter() - t0
        return out

    def _culled(self, gpu: GpuModel, draws: list[Draw], camera: Camera) -> tuple[list[Draw], Buffer]:
        """``draws`` with only the triangles that can cover a pixel centre of ``camera``'s picture
        (:mod:`renderer.cull`: the same picture, bit for bit), as ranges of ``gpu.cull_buffer``, and
        the index buffer to bind. A draw list of fewer than ``CULL_MIN_TRIANGLES`` triangles is drawn
        whole."""
        total = sum(d.index_count for d in draws) // 3
        if not self.cull or total < CULL_MIN_TRIANGLES:
            return draws, gpu.index_buffer
        model = gpu.model
        if gpu.projector is None:
            gpu.projector = Projector(model.positions)
        ranges = np.array([(d.first_index, d.index_count, d.vertex_offset) for d in draws], np.int64)
        kept, per_draw = cull_draws(gpu.projector, model.indices, ranges, camera.view_proj, camera.width,
                                    camera.height)
        if gpu.cull_buffer is None or gpu.cull_buffer.size < max(kept.nbytes, 4):
            if gpu.cull_buffer is not None:
                gpu.cull_buffer.destroy()
            gpu.cull_buffer = self.ctx.create_buffer(max(4 * total * 3, 4), self.vk.VK_BUFFER_USAGE_INDEX_BUFFER_BIT)
        gpu.cull_buffer.write(kept)
        out, first = [], 0
        for d, n in zip(draws, per_draw.tolist()):
            if n:
                out.append(dataclasses.replace(d, first_index=first, index_count=n))
            first += n
        return out, gpu.cull_buffer

    def one_pass(self, gpu: GpuModel) -> bool:
        """Whether :meth:`render_pair` draws ``gpu`` in one pass: every material OPAQUE (no MASK
        discard, no blending), so the shaded and the facing pictures share their nearest surfaces."""
        return all(m.alpha_mode == "OPAQUE" for m in gpu.model.materials)

    def render_pair(self, gpu: GpuModel, camera: Camera, lod: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(shaded, facing) renders of one view, as ``render(mode="shaded")`` and
        ``render(mode="facing")`` give them, from one pass when :meth:`one_pass` allows.

        The one pass draws without culling (as ``facing`` must) and writes the facing into alpha:
        its shaded picture therefore shows a single-sided back face where it is the nearest
        surface, where a culled render shows what lies behind it. For a model whose nearest
        surfaces face the eye (what the winding comparison holds every good model to) the two
        are the same picture; the checks compare a build with its source drawn the same way.
        """
        if not self.one_pass(gpu):
            return self.render(gpu, camera, lod=lod), self.render(gpu, camera, mode="facing", lod=lod)
        img = self.render(gpu, camera, mode="shaded+facing", lod=lod)
        a = img[..., 3]
        covered = a > 0
        facing = np.zeros_like(img)
        facing[..., 0] = np.where(a > 191, 255, np.where(covered, 188, 0))  # alpha 1.0 -> 255, 0.5 -> 128
        facing[..., 3] = np.where(covered, 255, 0)
        shaded = img.copy()
        shaded[..., 3] = facing[..., 3]
        return shaded, facing

    # ----------------------------------------------------------------------- teardown
    def close(self) -> None:
        """Destroy pipelines, layouts, targets and the white texture (not the context)."""
        vk, dev = self.vk, self.ctx.device
        if dev is None or self._vert is None:
            return
        self.ctx.wait_idle()
        self._destroy_targets()
        self.white.destroy()
        vk.vkDestroySampler(dev, self.white_sampler, None)
        for p in [*self._pipelines.values(), *self._lean.values(), *self._plain.values()]:
            vk.vkDestroyPipeline(dev, p, None)
        vk.vkDestroyPipelineLayout(dev, self.pipeline_layout, None)
        vk.vkDestroyDescriptorSetLayout(dev, self.set_layout, None)
        vk.vkDestroyShaderModule(dev, self._vert, None)
        vk.vkDestroyShaderModule(dev, self._frag, None)
        vk.vkDestroyShaderModule(dev, self._lean_vert, None)
        vk.vkDestroyShaderModule(dev, self._lean_frag, None)
        vk.vkDestroyShaderModule(dev, self._plain_vert, None)
        vk.vkDestroyShaderModule(dev, self._plain_frag, None)
        self._vert = None


def _decoded(tex: Texture, device: str, notes: list[str] | None) -> Texture:
    """``tex`` (a block format) decoded to RGBA8 levels, for a device that cannot sample it."""
    from assetpipe.core.ktx2 import (BLOCK_FORMATS, VK_FORMAT_R8G8B8A8_SRGB, VK_FORMAT_R8G8B8A8_UNORM,  # noqa: PLC0415
                                     decode_level)

    fmt = BLOCK_FORMATS[tex.vk_format]
    levels = [decode_level(lv, tex.vk_format, *tex.level_size(k)) for k, lv in enumerate(tex.levels)]
    if notes is not None:
        notes.append(f"{tex.name}: vkFormat {tex.vk_format} ({fmt.name}) is not supported for sampling by "
                     f"{device}: drew its levels decoded on the CPU")
    return Texture(name=tex.name, levels=levels, sampler=tex.sampler, from_ktx2=tex.from_ktx2,
                   vk_format=VK_FORMAT_R8G8B8A8_SRGB if fmt.srgb else VK_FORMAT_R8G8B8A8_UNORM)


def image_key(t: Texture) -> tuple:
    """The same texels: a KTX2 file (a built model's materials each read theirs), or the same
    level arrays (the reference's textures, one per material with that material's sampler)."""
    if t.from_ktx2 and t.name:
        return ("file", t.name, t.vk_format, len(t.levels))
    return ("levels", id(t.levels), t.vk_format)


def _first_levels(model: RenderModel, cams: list) -> dict[tuple, int]:
    """Per uploaded image (:func:`image_key`), the first level the shaded renders by ``cams``
    can sample: the smallest over every material and role drawing it
    (:func:`renderer.texture_levels.first_sampled_level`)."""
    from .texture_levels import first_sampled_level  # noqa: PLC0415

    tris: dict[int, list[np.ndarray]] = {}
    for mesh in model.meshes:
        lod = mesh.lods[0]
        idx = model.indices[lod.first_index:lod.first_index + lod.index_count].astype(np.int64)
        tris.setdefault(mesh.material, []).append(idx.reshape(-1, 3) + mesh.vertex_base)
    uv1 = model.uvs1 if model.uvs1 is not None else np.zeros_like(model.uvs)
    out: dict[tuple, int] = {}
    for i, m in enumerate(model.materials):
        drawn = np.concatenate(tris[i]) if i in tris else np.zeros((0, 3), np.int64)
        roles = ((m.texture, 0), (m.normal_texture, m.role_uv[0]), (m.metallic_roughness_texture, m.role_uv[1]),
                 (m.occlusion_texture, m.role_uv[2]), (m.emissive_texture, m.role_uv[3]))
        for t, uv_set in roles:
            if t is None:
                continue
            k = image_key(t)
            level = first_sampled_level(model.positions, uv1 if uv_set else model.uvs, drawn,
                                        (t.width, t.height), cams, len(t.levels),
                                        t.sampler.get("minFilter")) if drawn.size else len(t.levels) - 1
            out[k] = min(out.get(k, level), level)
    return out


def _from_level(t: Texture, first: int) -> Texture:
    """``t`` without its ``first`` finest levels (level ``first`` becomes level 0)."""
    if first <= 0:
        return t
    return dataclasses.replace(t, levels=list(t.levels[first:]),
                               size=t.level_size(first) if t.size is not None else None)
