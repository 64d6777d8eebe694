"""OpenEXR images as numpy arrays: a reader and a writer for what the bench meets, with numpy and zlib only.

Reads scanline files (single-part, or multi-part as Blender 5 writes its multilayer EXR) with NONE, ZIPS or
ZIP compression and HALF, FLOAT or UINT channels: what xi writes (ZIP, FLOAT, layers such as variance.R),
what Cycles writes when told to use ZIP, and what write() below writes. Mitsuba writes PIZ, which is not
read here: its images reach the bench as numpy arrays instead. Writes FLOAT channels with ZIP compression
and int, float, double and string attributes (xi reads them)."""
import struct
import zlib
from pathlib import Path

import numpy as np

MAGIC = b"\x76\x2f\x31\x01"
NONE, ZIPS, ZIP = 0, 2, 3
LINES_PER_CHUNK = {NONE: 1, ZIPS: 1, ZIP: 16}
COMPRESSION_NAMES = ["NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB"]
PIXEL_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}


def _attrs(data, pos):
    """One header's attributes (name -> (type, raw bytes)) from POS, and the offset after its end byte."""
    attrs = {}
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        (size,) = struct.unpack_from("<i", data, type_end + 1)
        attrs[data[pos:name_end].decode()] = (data[name_end + 1:type_end].decode(),
                                             data[type_end + 5:type_end + 5 + size])
        pos = type_end + 5 + size
    return attrs, pos + 1


def _headers(data):
    """The headers of a single-part or multi-part scanline file, and the offset where they end."""
    if data[:4] != MAGIC:
        raise ValueError("not an OpenEXR file")
    (version,) = struct.unpack_from("<i", data, 4)
    if version & 0xa00:  # tiled or deep
        raise ValueError("only scanline OpenEXR files are read")
    if not version & 0x1000:
        attrs, pos = _attrs(data, 8)
        return [attrs], pos, False
    headers, pos = [], 8
    while data[pos] != 0:  # multi-part (Blender 5's multilayer files): headers until an empty one
        attrs, pos = _attrs(data, pos)
        if attrs.get("type", ("", b"scanlineimage"))[1].rstrip(b"\0") != b"scanlineimage":
            raise ValueError("only scanline OpenEXR parts are read")
        headers.append(attrs)
    return headers, pos + 1, True


def _channels(raw):
    out, pos = [], 0
    while raw[pos] != 0:
        end = raw.index(b"\0", pos)
        kind, _, xs, ys = struct.unpack_from("<iB3xii", raw, end + 1)
        if (xs, ys) != (1, 1):
            raise ValueError("subsampled channels are not read")
        out.append((raw[pos:end].decode(), PIXEL_TYPES[kind]))
        pos = end + 17
    return out


def attributes(raw_attrs):
    """Readable attribute values: int, float, double, string, box2i; others are left out."""
    formats = {"int": "<i", "float": "<f", "double": "<d", "box2i": "<4i"}
    out = {}
    for name, (kind, value) in raw_attrs.items():
        if kind in formats:
            v = struct.unpack(formats[kind], value)
            out[name] = v[0] if len(v) == 1 else v
        elif kind == "string":
            out[name] = value.decode()
    return out


def _unzip(data, size):
    """ZIP and ZIPS: zlib, then the byte predictor and the two interleaved halves undone."""
    t = np.frombuffer(zlib.decompress(data), np.uint8)
    if t.size != size:
        raise ValueError("a ZIP chunk of the wrong size")
    t = ((np.cumsum(t.astype(np.int64) - 128) + 128) % 256).astype(np.uint8)  # byte i = byte i-1 + d_i - 128
    out = np.empty(size, np.uint8)
    half = (size + 1) // 2
    out[0::2], out[1::2] = t[:half], t[half:]
    return out


def read(path):
    """(channels, attributes): each channel name ('R', 'variance.G', 'spp', ...) as a float64 (H, W) array
    top row first, and the first header's readable attributes. In a multi-part file a channel whose name
    another part also uses is prefixed with its part's name."""
    data = Path(path).read_bytes()
    headers, pos, multipart = _headers(data)
    parts = []
    for raw_attrs in headers:
        attrs = attributes(raw_attrs)
        compression = raw_attrs["compression"][1][0]
        if compression not in LINES_PER_CHUNK:
            raise ValueError(f"{path}: {COMPRESSION_NAMES[compression]} compression is not read "
                             f"(NONE, ZIPS, ZIP are)")
        x0, y0, x1, y1 = attrs["dataWindow"]
        chunks = (y1 - y0 + LINES_PER_CHUNK[compression]) // LINES_PER_CHUNK[compression]
        parts.append((attrs, compression, _channels(raw_attrs["channels"][1]), chunks))
    names = [name for _, _, channels, _ in parts for name, _ in channels]
    out = {}
    for index, (attrs, compression, channels, chunks) in enumerate(parts):
        offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
        pos += 8 * chunks
        x0, y0, x1, y1 = attrs["dataWindow"]
        w, h = x1 - x0 + 1, y1 - y0 + 1
        per_chunk = LINES_PER_CHUNK[compression]
        line_bytes = sum(dt.itemsize for _, dt in channels) * w
        prefix = attrs.get("name", "") + "." if multipart else ""
        images = {name: np.empty((h, w), np.float64) for name, _ in channels}
        for offset in offsets:
            offset += 4 if multipart else 0  # (the part number)
            y, size = struct.unpack_from("<ii", data, offset)
            lines = min(per_chunk, y1 + 1 - y)
            raw = data[offset + 8:offset + 8 + size]
            expected = lines * line_bytes
            block = np.frombuffer(raw, np.uint8) if size == expected or compression == NONE else _unzip(raw, expected)
            at = 0
            for line in range(lines):
                for name, dt in channels:
                    n = w * dt.itemsize
                    images[name][y - y0 + line] = np.frombuffer(block[at:at + n].tobytes(), dt)
                    at += n
        for name, image in images.items():
            out[prefix + name if names.count(name) > 1 else name] = image
    return out, attributes(headers[0])


def rgb(path, layer=""):
    """The (H, W, 3) float64 image of LAYER ('' for R,G,B; 'noisy' for noisy.R, ...) and the attributes."""
    channels, attrs = read(path)
    prefix = f"{layer}." if layer else ""
    return np.stack([channels[prefix + c] for c in "RGB"], axis=-1), attrs


def _attribute(name, value):
    if isinstance(value, bool) or isinstance(value, int):
        kind, raw = "int", struct.pack("<i", value)
    elif isinstance(value, float):
        kind, raw = "double", struct.pack("<d", value)
    else:
        kind, raw = "string", str(value).encode()
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(raw)) + raw


def _zip(raw):
    t = np.empty(raw.size, np.uint8)
    half = (raw.size + 1) // 2
    t[:half], t[half:] = raw[0::2], raw[1::2]
    d = t.astype(np.int16)
    d[1:] = (t[1:].astype(np.int16) - t[:-1].astype(np.int16) + 128) % 256
    return zlib.compress(d.astype(np.uint8).tobytes(), 6)


def write(path, image, attrs=None):
    """IMAGE ((H, W, 3), linear) as R, G, B FLOAT channels, ZIP compressed, with ATTRS (name -> int, float
    (written as double) or str). Written under a temporary name and renamed."""
    img = np.ascontiguousarray(image, np.float32)
    h, w, _ = img.shape
    chlist = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in "BGR") + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = [b"channels\0chlist\0" + struct.pack("<i", len(chlist)) + chlist,
              b"compression\0compression\0" + struct.pack("<iB", 1, ZIP),
              b"dataWindow\0box2i\0" + struct.pack("<i", 16) + box,
              b"displayWindow\0box2i\0" + struct.pack("<i", 16) + box,
              b"lineOrder\0lineOrder\0" + struct.pack("<iB", 1, 0),
              b"pixelAspectRatio\0float\0" + struct.pack("<if", 4, 1.0),
              b"screenWindowCenter\0v2f\0" + struct.pack("<iff", 8, 0.0, 0.0),
              b"screenWindowWidth\0float\0" + struct.pack("<if", 4, 1.0)]
    header += [_attribute(k, v) for k, v in (attrs or {}).items()]
    head = MAGIC + struct.pack("<i", 2) + b"".join(header) + b"\0"
    chunks = []
    for y in range(0, h, 16):
        rows = img[y:y + 16]
        # per scanline: all B, then all G, then all R (channels in name order)
        raw = np.ascontiguousarray(rows[:, :, ::-1].transpose(0, 2, 1)).view(np.uint8).reshape(-1)
        packed = _zip(raw)
        if len(packed) >= raw.size:
            packed = raw.tobytes()
        chunks.append(struct.pack("<ii", y, len(packed)) + packed)
    offset = len(head) + 8 * len(chunks)
    table = []
    for ch in chunks:
        table.append(struct.pack("<Q", offset))
        offset += len(ch)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(head + b"".join(table) + b"".join(chunks))
    tmp.replace(path)
