"""Synthetic datasets on disk: chunk files written by independent shards, and a torch ``Dataset`` over them.

Layout of a dataset folder::

    meta.json                 generator settings, n, seed, version (identical from every shard)
    chunk-000000.npz          samples [0, CHUNK), chunk c holds [c * CHUNK, min((c + 1) * CHUNK, n))
    chunk-000001.npz          ...

Sharding: shard I of K writes the chunks c with ``c % K == I``. The files do not depend on K: the same
(seed, n, settings) gives the same folder, byte for byte, however many machines wrote it. A chunk is written
atomically once complete; a rerun skips the chunks already there (resumable).

A chunk file is an ``.npz`` with one member per sample and key, ``"{index:09d}/{key}"`` (so one sample is read
without decompressing its neighbours), plus ``"index"`` (the global indices it holds). Keys and units of a sample
(camera frame = OpenCV, mm; pixels with the centre of the top-left pixel at (0, 0)):

=====================  ===================  ===========================================================
key                    shape, dtype         meaning
=====================  ===================  ===========================================================
rgb                    (S, S, 3) uint8      the image
depth                  (S, S) uint16        sensor depth, mm, 0 = missing (``render.depth_noise``)
depth_clean            (S, S) float32       exact camera z of the front surface, mm, 0 = none
silhouette             (S, S) bool          pixels whose front surface is the foot (not the leg)
labels                 (S, S) uint8         0 floor/background, 1 foot, 2 leg, 3 reference object
joints2d               (18, 2) float32      projected joints, px
joints_visible         (18,) bool           in the image and not hidden (``render._visible``)
joints3d               (18, 3) float32      joints, camera frame, mm
vertices               (V, 3) float32       foot mesh vertices, camera frame, mm (faces: ``model.faces(side)``)
shape                  (K,) float32         PCA coefficients, SD units
angles                 (22,) float32        joint angles, radians, ``skeleton.DOF_NAMES`` order
side                   () int8              0 left, 1 right
K                      (3, 3) float64       intrinsics, px
cam_from_foot          (4, 4) float64       foot frame -> camera: ``vertices = R @ model(...) + t``
cam_from_scene         (4, 4) float64       scene (floor z = 0) frame -> camera
ref_type               () int8              0 none, 1 a4, 2 card, 3 marker (``ReferenceKind.dataset_id``)
ref_corners3d          (4, 3) float32       reference rectangle corners, camera frame, mm (NaN if none)
ref_corners2d          (4, 2) float32       their projections, px (NaN if none)
ref_corners_visible    (4,) bool            in the image and not hidden
view_id                () int16             thesis viewpoint 0..21, -1 for a random view
lifted                 () bool              the foot is lifted off the floor
index                  () int64             global sample index
=====================  ===================  ===========================================================
"""

from __future__ import annotations

import io
import itertools
import json
import os
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict
from pathlib import Path

import numpy as np
from torch.utils.data import Dataset

from footmesh import __version__
from footmesh.report import ZIP_DATE_TIME, atomic_path
from footmesh.synth.scene import SynthConfig

CHUNK = 256
"""Samples per chunk file."""
META = "meta.json"
FORMAT = "footmesh-synth-4"
"""What ``meta.json``'s ``format`` says this version writes; a new one whenever the same (seed, n, settings) would
give other bytes. 1: the first. 2: IK poses (15 % of samples) solved by ``synth.posing`` (compiled) instead of
``model.ik`` (torch): the same algorithm and distribution, but other rounding, and about half of those feet
take another exact solution of the redundant toe chains (the seeds tie to within rounding). 3: the same arrays
as 2, deflated by ISA-L instead of zlib (other bytes, about 6 % larger). 4: the sensor noise (RGB and depth)
drawn by compiled kernels (SplitMix64, a ziggurat) instead of numpy's generator, and the floor's camera rays
made inside ``kernels.floor_shade`` (other draws; floor depth rounded otherwise, within about 1e-13 relative),
and coarser shadow maps (``render.CAST_TEXEL_MM``, ``CONTACT_TEXEL_MM``: RGB differs along shadow edges)."""
FORMATS_READ = ("footmesh-synth-1", "footmesh-synth-2", "footmesh-synth-3", FORMAT)
"""Formats ``SynthDataset`` reads (every one so far: same keys, shapes and units); a folder of another is refused."""
COMPRESS_LEVEL = 1
"""Deflate level of the chunk files' members (ISA-L's igzip, ``isal``): its level 1 deflates a sample in about
3 ms where zlib's level 1 took 13-15 ms, for about 6 % more bytes (format 3)."""


def chunk_name(chunk: int) -> str:
    return f"chunk-{chunk:06d}.npz"


def sample_key(index: int, key: str) -> str:
    return f"{index:09d}/{key}"


def shard_chunks(n: int, shards: int, shard_index: int, chunk: int = CHUNK) -> list[int]:
    """Chunk numbers that shard ``shard_index`` of ``shards`` writes for ``n`` samples."""
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if shards < 1 or not 0 <= shard_index < shards:
        raise ValueError(f"shard index must be in 0..{shards - 1} for {shards} shards, got {shard_index}")
    n_chunks = -(-n // chunk)
    return [c for c in range(n_chunks) if c % shards == shard_index]


def chunk_indices(c: int, n: int, chunk: int = CHUNK) -> range:
    return range(c * chunk, min((c + 1) * chunk, n))


def write_chunk(path: str | os.PathLike, samples: Iterable[dict[str, np.ndarray]]) -> None:
    """Write samples into one chunk ``.npz`` atomically, with reproducible bytes (fixed member dates).

    A plain zip of deflated ``.npy`` members (``np.load`` and ``zipfile`` read it as usual), written here because
    the deflate streams come from ISA-L (``isal``), several times faster than zlib at level 1.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        zf = _ZipWriter(f)
        indices = []
        for sample in samples:
            index = int(sample["index"])
            indices.append(index)
            for key, value in sample.items():
                zf.add_npy(sample_key(index, key), value)
        zf.add_npy("index", np.asarray(indices, dtype=np.int64))
        zf.close()


class _ZipWriter:
    """A minimal zip writer (PKWARE APPNOTE 4.3: local headers, central directory, end record; no zip64) whose
    members are ``.npy`` files deflated by ISA-L, dated 1980-01-01 (``report.ZIP_DATE_TIME``), mode 0644."""

    _DOS_DATE = ((ZIP_DATE_TIME[0] - 1980) << 9) | (ZIP_DATE_TIME[1] << 5) | ZIP_DATE_TIME[2]
    _DOS_TIME = (ZIP_DATE_TIME[3] << 11) | (ZIP_DATE_TIME[4] << 5) | (ZIP_DATE_TIME[5] // 2)
    _MAX = 0xFFFF_FFFF

    def __init__(self, f) -> None:
        from isal import isal_zlib

        self.isal_zlib = isal_zlib
        self.f = f
        self.central: list[bytes] = []
        self.offset = 0
        self._headers: dict[tuple, bytes] = {}

    def add_npy(self, name: str, value: np.ndarray) -> None:
        raw = self._npy(np.asanyarray(value))
        compressor = self.isal_zlib.compressobj(COMPRESS_LEVEL, self.isal_zlib.DEFLATED, -15)
        data = compressor.compress(raw) + compressor.flush()  # raw deflate (wbits -15), as zip members hold
        crc = zlib.crc32(raw)
        filename = f"{name}.npy".encode()
        if len(raw) >= self._MAX or len(data) >= self._MAX or self.offset >= self._MAX or len(self.central) >= 0xFFFF:
            raise ValueError(f"chunk too large for a zip without zip64 ({name}); write smaller chunks")
        # version needed 2.0, flags 0, method 8 (deflate), time, date, crc, sizes, name length, no extra field
        fields = (20, 0, 8, self._DOS_TIME, self._DOS_DATE, crc, len(data), len(raw), len(filename))
        local = struct.pack("<IHHHHHIIIHH", 0x04034B50, *fields, 0)
        # made by 3.0 on Unix, the same fields, no comment, disk 0, internal 0, external: mode 0644, offset
        central = struct.pack("<IH", 0x02014B50, (3 << 8) | 20) + struct.pack(
            "<HHHHHIIIHHHHHII", *fields, 0, 0, 0, 0, 0o644 << 16, self.offset
        )
        self.f.write(local + filename)
        self.f.write(data)
        self.central.append(central + filename)
        self.offset += len(local) + len(filename) + len(data)

    def _npy(self, value: np.ndarray) -> bytes:
        """The ``.npy`` file of ``value`` (``np.lib.format.write_array``'s bytes; its header made once per dtype and
        shape)."""
        if value.dtype.hasobject:
            raise ValueError("object arrays are not written into chunk files")
        key = (value.dtype.str, value.shape, value.flags.f_contiguous and not value.flags.c_contiguous)
        header = self._headers.get(key)
        if header is None:
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, value, allow_pickle=False)
            header = self._headers[key] = buffer.getvalue()[: buffer.tell() - value.nbytes]
        return header + value.tobytes(order="F" if key[2] else "C")

    def close(self) -> None:
        directory = b"".join(self.central)
        self.f.write(directory)
        n = len(self.central)
        self.f.write(struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, n, n, len(directory), self.offset, 0))


def make_meta(config: SynthConfig, n: int, seed: int, chunk: int = CHUNK) -> dict:
    return {"format": FORMAT, "n": n, "seed": seed, "chunk": chunk, "config": asdict(config)}


def check_meta(out: Path, meta: dict) -> None:
    """Write ``meta.json``, or check that the one there describes the same dataset (no mixed settings)."""
    path = out / META
    if path.is_file():
        old = json.loads(path.read_text())
        if old.get("format") != meta["format"]:
            raise ValueError(
                f"{out} holds a dataset of format {old.get('format')!r} ({path}); this version writes "
                f"{meta['format']!r}, whose samples differ, so it cannot add chunks to it: use another --out"
            )
        old_cmp = {k: v for k, v in old.items() if k != "version"}
        # a field added to SynthConfig since, at its default, renders what the dataset was made with
        defaults = json.loads(json.dumps(asdict(SynthConfig())))
        added = {k: v for k, v in defaults.items() if k not in old_cmp["config"]}
        old_cmp["config"] = {**old_cmp["config"], **added}
        if json.loads(json.dumps(meta)) != old_cmp:
            raise ValueError(f"{out} holds a dataset made with other settings ({path}); use another --out")
        return
    from footmesh.report import write_json

    write_json(path, {**meta, "version": __version__})


def generate(
    out: str | os.PathLike,
    n: int,
    seed: int = 0,
    config: SynthConfig | None = None,
    shards: int = 1,
    shard_index: int = 0,
    workers: int = 1,
    progress: bool = True,
    chunk: int = CHUNK,
    threads: int | None = None,
) -> list[Path]:
    """Write this shard's chunks of a dataset into ``out``; complete chunks already there are skipped.

    ``workers`` processes render (default 1: this one); within one process ``threads`` threads render samples
    side by side (default: one per core when ``workers`` is 1, else 1; the compiled kernels, numpy and torch
    release the GIL), while another thread compresses and writes the previous chunk. The files are the same
    whatever ``workers`` and ``threads`` (each sample is a function of (seed, index) alone; tested).

    Returns:
        the chunk files written by this call.
    """
    config = config or SynthConfig()
    if threads is None:
        threads = (os.cpu_count() or 1) if workers == 1 else 1
    if threads < 1:
        raise ValueError(f"threads must be at least 1, got {threads}")
    out_dir = Path(out)
    chunks = shard_chunks(n, shards, shard_index, chunk)
    out_dir.mkdir(parents=True, exist_ok=True)
    check_meta(out_dir, make_meta(config, n, seed, chunk))
    todo = [c for c in chunks if not (out_dir / chunk_name(c)).is_file()]
    total = sum(len(chunk_indices(c, n, chunk)) for c in todo)
    from concurrent.futures import ThreadPoolExecutor

    from tqdm import tqdm

    written = []
    with (
        tqdm(total=total, unit="sample", disable=not progress, desc=f"shard {shard_index}/{shards}") as bar,
        ThreadPoolExecutor(1, thread_name_prefix="footmesh-synth-write") as writer,
    ):
        render = _renderer_pool(config, seed, workers, threads)
        pending = None  # the chunk being written while the next one renders (two chunks in memory at most)
        try:
            samples_of = render.map([i for c in todo for i in chunk_indices(c, n, chunk)])
            for c in todo:
                samples = []
                for _ in chunk_indices(c, n, chunk):
                    samples.append(next(samples_of))
                    bar.update(1)
                if pending is not None:
                    written.append(pending.result())
                pending = writer.submit(_write_chunk_to, out_dir / chunk_name(c), samples)
            if pending is not None:
                written.append(pending.result())
        finally:
            render.close()
    return written


def _write_chunk_to(path: Path, samples: list[dict[str, np.ndarray]]) -> Path:
    write_chunk(path, samples)
    return path


class _renderer_pool:  # noqa: N801 (a small callable helper)
    """``map(indices) -> samples in order``: in this process (``threads`` threads) or in ``workers`` processes."""

    def __init__(self, config: SynthConfig, seed: int, workers: int, threads: int = 1) -> None:
        self.seed = seed
        self.pool = self.threads = None
        if workers > 1:
            import multiprocessing as mp

            self.pool = mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=(config,))
            return
        _init_worker(config)
        if threads > 1:
            from concurrent.futures import ThreadPoolExecutor

            self.threads = ThreadPoolExecutor(threads, thread_name_prefix="footmesh-synth", initializer=_limit_threads)
        self.window = 4 * threads

    def map(self, indices: list[int]) -> Iterator[dict[str, np.ndarray]]:
        args = [(self.seed, i) for i in indices]
        if self.pool is not None:
            return self.pool.imap(_render_one, args, chunksize=4)
        if self.threads is not None:
            return _ordered_map(self.threads, _render_one, args, self.window)
        return map(_render_one, args)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
        if self.threads is not None:
            self.threads.shutdown(cancel_futures=True)


def _ordered_map(executor, func: Callable, args: list, window: int) -> Iterator:
    """``map(func, args)`` on ``executor``, in order, with at most ``window`` calls submitted ahead."""
    from collections import deque

    pending = iter(args)
    queue: deque = deque(executor.submit(func, a) for a in itertools.islice(pending, window))
    while queue:
        result = queue.popleft().result()
        for a in itertools.islice(pending, 1):
            queue.append(executor.submit(func, a))
        yield result


_WORKER_RENDERER = None


def _limit_threads() -> None:
    """One thread for torch, OpenMP and BLAS, set from the calling thread.

    OpenMP's thread count is a per-thread setting: a thread that does not set it runs its first torch matrix
    product (MKL) on every core, whose sums come out in another order (different bits).
    """
    import torch
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    torch.set_num_threads(1)


def _init_worker(config: SynthConfig) -> None:
    global _WORKER_RENDERER
    from footmesh.synth.render import Renderer

    _limit_threads()
    _WORKER_RENDERER = Renderer(config)


def _render_one(args: tuple[int, int]) -> dict[str, np.ndarray]:
    seed, index = args
    return _WORKER_RENDERER.render(seed, index)


class SynthDataset(Dataset):
    """Random access to the samples of a dataset folder, as a ``torch.utils.data.Dataset``.

    ``dataset[i]`` is the sample with global index ``self.indices[i]`` as a dict of numpy arrays (``keys`` to
    read fewer). Indices are sorted, so with every chunk present ``dataset[i]`` is sample ``i``. Chunk files are
    opened lazily per process (safe with ``DataLoader`` workers).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        keys: Iterable[str] | None = None,
        transform: Callable[[dict[str, np.ndarray]], object] | None = None,
    ) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"synthetic dataset folder not found: {self.root}")
        meta = self.root / META
        self.meta = json.loads(meta.read_text()) if meta.is_file() else {}
        if "format" in self.meta and self.meta["format"] not in FORMATS_READ:
            raise ValueError(
                f"{meta}: dataset format {self.meta['format']!r} is not one this version reads {FORMATS_READ}; "
                "update footmesh or write the dataset again"
            )
        files = sorted(self.root.glob("chunk-*.npz"))
        if not files:
            raise FileNotFoundError(f"no chunk-*.npz files in {self.root}; write some with `footmesh synth`")
        self.files = files
        self.keys = list(keys) if keys is not None else None
        self.transform = transform
        locations = []
        for f_id, f in enumerate(files):
            with np.load(f) as npz:
                for index in npz["index"]:
                    locations.append((int(index), f_id))
        locations.sort()
        self.indices = np.array([i for i, _ in locations], dtype=np.int64)
        self._file_of = np.array([f for _, f in locations], dtype=np.int64)
        self._open: dict[int, object] = {}
        self._pid = os.getpid()

    def __len__(self) -> int:
        return len(self.indices)

    def __repr__(self) -> str:
        return f"SynthDataset({self.root}, samples={len(self)}, chunks={len(self.files)})"

    def __getitem__(self, i: int):
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} out of range for {len(self)} samples")
        index, f_id = int(self.indices[i]), int(self._file_of[i])
        npz = self._npz(f_id)
        keys = self.keys
        if keys is None:
            prefix = f"{index:09d}/"
            keys = self.keys = [k[len(prefix) :] for k in npz.files if k.startswith(prefix)]
        sample = {k: npz[sample_key(index, k)] for k in keys}
        return self.transform(sample) if self.transform is not None else sample

    def _npz(self, f_id: int):
        if os.getpid() != self._pid:  # forked into a DataLoader worker: do not share file handles
            self._open, self._pid = {}, os.getpid()
        if f_id not in self._open:
            self._open[f_id] = np.load(self.files[f_id])
        return self._open[f_id]
