"""Fuzz the volume readers (issue 17): seeded mutants of valid MetaImage, NRRD, NIfTI, NumPy,
InVesalius and DICOM files -- hostile header values, deleted and repeated fields, corrupted
binary headers, byte-level damage, special files -- each through ``softvr.volume.load`` in a
child with a timeout and an address-space limit (``harness.run_reader``).

Every input must end ``ok`` or ``clean`` (an InputError naming the file and a field): no
traceback, crash, hang or memory blow-up."""

from __future__ import annotations

import gzip
import io
import os
import plistlib
import random
import struct
import tarfile
import zipfile

import numpy as np
import pydicom
import pydicom.data
import pytest
from harness import run_reader, summary
from pydicom.fileset import FileSet

from softvr.volume import SUPPORTED_DTYPES, Volume, load, save

SEED = 17
#: Mutants per seed file (x 14 seed files, + 11 special files: 1 271 inputs).
PER_SEED = 90
#: The children read with a voxel limit of 4 M (SOFTVR_MAX_ELEMENTS) and count any input after
#: which their peak resident memory exceeds 384 MiB (imports: ~110 MiB; 4 M float64 voxels:
#: 32 MiB) as ``memory``: an allocation beyond the limit.
CHILD_ENV = {"SOFTVR_MAX_ELEMENTS": str(1 << 22), "SOFTVR_FUZZ_RSS": str(384 << 20)}

#: Values a broken exporter or an attacker writes into a header field.
HOSTILE = ["1e308", "-1e308", "-5", "-1", "0", "1", "2", "4", "7", "9", "99999999999999999999", "2147483648",
           "9223372036854775807", "nan", "inf", "-inf", "", "x", "é\u202e", "a\x00b", "1 2", "1 2 3 4 5 6 7 8 9 10",
           "100000 100000 100000", "65535 65535 65535", "1000 1000 1000", "0 0 0", "-1 2 3", "3 3 3 3",
           "/etc/passwd", "../../../../etc/passwd", "/dev/zero", "pipe.raw", "LIST", "v%03d.raw 1 3 1", "LOCAL",
           "MET_STRING", "MET_DOUBLE", "MET_CHAR", "block", "double", "uint64", "True", "False", "gzip", "bzip2",
           "ascii", "hex", "big", "little", "none", "(nan,0,0) (0,1,0) (0,0,1)", "(0,0,0) (0,0,0) (0,0,0)",
           "(1,0,0) (0,1,0)", "a" * 300, "9" * 5000]


def _volume() -> Volume:
    rng = np.random.default_rng(SEED)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return Volume(rng.integers(-1000, 2000, (4, 5, 6)).astype(np.int16), spacing=(0.5, 0.75, 1.25),
                  origin=(10, -20, 3), direction=rot)


def _seeds(folder) -> list[tuple[str, dict[str, bytes]]]:
    """(main file name, {file name: bytes}) of each valid seed input, companions included."""
    vol = _volume()
    out = []
    for name in ("v.mha", "v.mhd", "v.nrrd", "v.nhdr", "v.nii", "v.nii.gz", "v.npy", "v.npz"):
        sub = folder / f"seed_{name.replace('.', '_')}"
        sub.mkdir()
        save(vol, sub / name)
        out.append((name, {f.name: f.read_bytes() for f in sub.iterdir()}))
    data = vol.data.transpose(2, 1, 0).astype("<i2")
    out.append(("c.mha", {"c.mha": b"ObjectType = Image\nNDims = 3\nDimSize = 4 5 6\nElementType = MET_SHORT\n"
                          b"CompressedData = True\nElementDataFile = LOCAL\n" + gzip.compress(data.tobytes())}))
    out.append(("t.nrrd", {"t.nrrd": b"NRRD0004\ntype: short\ndimension: 4\nsizes: 2 3 2 2\nendian: big\n"
                           b"encoding: ascii\nkinds: domain domain domain list\n\n"
                           + " ".join(map(str, range(24))).encode()}))
    plist = plistlib.dumps({"matrix": {"filename": "matrix.dat", "shape": [6, 5, 4], "dtype": "int16"},
                            "spacing": [0.5, 0.75, 1.25]})
    blob = io.BytesIO()
    with tarfile.open(fileobj=blob, mode="w:gz") as tar:
        for member, content in (("p/main.plist", plist), ("p/matrix.dat", data.tobytes())):
            info = tarfile.TarInfo(member)
            info.size = len(content)
            tar.addfile(info, io.BytesIO(content))
    out.append(("v.inv3", {"v.inv3": blob.getvalue()}))
    sub = folder / "seed_dicom"
    save(vol, sub)
    first = sorted(sub.iterdir())[0]
    out.append(("v.dcm", {"v.dcm": first.read_bytes()}))
    rtdose = os.path.join(os.path.dirname(pydicom.data.__file__), "test_files", "rtdose.dcm")  # multi-frame
    with open(rtdose, "rb") as f:
        out.append(("dose.dcm", {"dose.dcm": f.read()}))
    fileset = FileSet()  # a DICOMDIR listing the series, its images in pydicom's folder tree
    for f in sorted(sub.iterdir()):
        ds = pydicom.dcmread(f)
        ds.StudyID = "1"
        fileset.add(ds)
    fileset.write(folder / "seed_dicomdir")
    tree = folder / "seed_dicomdir"
    out.append(("DICOMDIR", {str(f.relative_to(tree)): f.read_bytes() for f in tree.rglob("*") if f.is_file()}))
    return out


#: Sizes that claim more voxels than the limit, or than the file holds.
BIG_SIZES = ["100000 100000 100000", "65535 65535 65535", "1000 1000 1000", "2048 2048 1024", "4096 4096 4096",
             "1 1 9223372036854775807", "200 200 200", "3037000500 3037000500 1"]


def _text_mutant(text: bytes, rng: random.Random, sep: bytes) -> bytes:
    """A text header (``sep`` = b"=" MetaImage, b":" NRRD) with its sizes set to a huge claim
    (a quarter of them) or one to three fields set to hostile values, deleted, repeated or
    added."""
    head, found, payload = text.partition(b"\n\n") if sep == b":" else (text, b"", b"")
    if sep == b"=" and b"ElementDataFile = LOCAL\n" in text:
        head, found, payload = text.partition(b"ElementDataFile = LOCAL\n")
        head += found
        found = b""
    lines = head.split(b"\n")
    size_key = b"DimSize" if sep == b"=" else b"sizes"
    if rng.random() < 0.25:
        lines = [size_key + sep + b" " + rng.choice(BIG_SIZES).encode() if line.split(sep)[0].strip() == size_key
                 else line for line in lines]
        return b"\n".join(lines) + found + payload
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(1 if sep == b":" else 0, max(len(lines), 2))
        i = min(i, len(lines) - 1)
        key = lines[i].split(sep)[0].strip() or b"NDims"
        action = rng.random()
        if action < 0.1:
            del lines[i]
        elif action < 0.2:
            lines.insert(i, lines[i])
        elif action < 0.3:
            extra = rng.choice([b"ElementNumberOfChannels", b"HeaderSize", b"BinaryDataByteOrderMSB",
                                b"TransformMatrix", b"line skip", b"byte skip", b"data file", b"kinds",
                                b"space origin", b"spacings", b"CompressedData", b"ElementSpacing"])
            lines.insert(i, extra + sep + b" " + rng.choice(HOSTILE).encode("utf-8", "surrogateescape"))
        else:
            lines[i] = key + sep + b" " + rng.choice(HOSTILE).encode("utf-8", "surrogateescape")
        if not lines:
            break
    return b"\n".join(lines) + found + payload


#: (offset, struct format) of the NIfTI-1 header fields a mutant overwrites.
_NIFTI_FIELDS = [(0, "<i"), (40, "<h"), (42, "<h"), (44, "<h"), (46, "<h"), (48, "<h"), (70, "<h"), (72, "<h"),
                 (76, "<f"), (80, "<f"), (108, "<f"), (112, "<f"), (116, "<f"), (252, "<h"), (254, "<h"),
                 (280, "<f"), (344, "4s")]


def _nifti_mutant(raw: bytes, rng: random.Random) -> bytes:
    b = bytearray(raw)
    if rng.random() < 0.25:  # a huge size claim: dim[1..3]
        struct.pack_into("<3h", b, 42, *(rng.choice([1000, 2048, 4096, 32767]) for _ in range(3)))
        return bytes(b)
    for _ in range(rng.randint(1, 3)):
        offset, fmt = rng.choice(_NIFTI_FIELDS)
        if fmt == "<h":
            value = rng.choice([-32768, -5, -1, 0, 1, 2, 3, 4, 5, 7, 8, 9, 16, 64, 128, 255, 256, 512, 1024, 2048,
                                4096, 32767])
        elif fmt == "<i":
            value = rng.choice([0, 348, 540, -1, 2**31 - 1, 0x5C010000])
        elif fmt == "<f":
            value = rng.choice([0.0, -1.0, 1e30, -1e30, float("nan"), float("inf"), 1e-30, 352.0, 3.5e9, 7.0])
        else:
            value = rng.choice([b"n+1\0", b"ni1\0", b"n+2\0", b"xxxx"])
        struct.pack_into(fmt, b, offset, value)
    return bytes(b)


def _npy_mutant(raw: bytes, rng: random.Random) -> bytes:
    header_len = struct.unpack("<H", raw[8:10])[0]
    text = raw[10:10 + header_len].decode("latin-1")
    text = rng.choice([
        text.replace("(4, 5, 6)", rng.choice(["(1000000, 1000000, 1000000)", "(-1, 5, 6)", "(40, 50, 60)",
                                              "(2**40,)", "()", "(0, 5, 6)", "(4, 5, 6, 7)"])),
        text.replace("'<i2'", rng.choice(["'|O'", "'<c16'", "'V8'", "[('a', '<i2')]", "'<i2' * 9", "'>f8'"])),
        text.replace("False", rng.choice(["True", "1", "None"])),
        text[: rng.randrange(len(text))],
    ])
    body = text.encode("latin-1")
    return raw[:8] + struct.pack("<H", len(body)) + body + raw[10 + header_len:]


#: DICOM elements a mutant sets, with values of their own type that a reader must survive.
_DICOM_VALUES = {
    "Rows": [0, 1, 2, 65535], "Columns": [0, 1, 3, 65535], "NumberOfFrames": ["0", "-1", "2", "100000", "x"],
    "BitsAllocated": [0, 1, 7, 12, 32, 64], "BitsStored": [0, 33], "PixelRepresentation": [1, 2],
    "SamplesPerPixel": [0, 3], "PhotometricInterpretation": ["RGB", "PALETTE COLOR", "YBR_FULL"],
    "ImagePositionPatient": [["nan", "0", "0"], ["1e308", "1", "1"], ["1", "2"]],
    "ImageOrientationPatient": [["0"] * 6, ["1", "0", "0", "1", "0", "0"], ["nan"] * 6, ["1", "0"]],
    "PixelSpacing": [["0", "0"], ["-1", "1"], ["inf", "1"], ["1"]], "SliceThickness": ["0", "-5", "nan"],
    "RescaleSlope": ["0", "nan", "1e308", "-1"], "RescaleIntercept": ["inf", "1e308"],
    "GridFrameOffsetVector": [["0"] * 15, ["0", "5"], [str(v) for v in range(15, 0, -1)]],
    "DoseGridScaling": ["nan", "0", "1e308"], "SeriesInstanceUID": ["", "1.2.3"],
    "ReferencedFileID": [["..", "..", "etc", "passwd"], ["/etc/passwd"], ["NOPE"], ["PT000000"]],
    "DirectoryRecordType": ["SERIES", "IMAGE", "PATIENT"],
}


def _dicom_mutant(raw: bytes, rng: random.Random) -> bytes:
    """One to three DICOM elements (top level or in the DICOMDIR's records) set to hostile
    values of their own type, or deleted; the bytes as pydicom writes them."""
    ds = pydicom.dcmread(io.BytesIO(raw))
    targets = [ds] + list(ds.get("DirectoryRecordSequence", []))
    for _ in range(rng.randint(1, 3)):
        target = rng.choice(targets)
        keyword = rng.choice(sorted(_DICOM_VALUES))
        if rng.random() < 0.15:
            if keyword in target:
                delattr(target, keyword)
        else:
            setattr(target, keyword, rng.choice(_DICOM_VALUES[keyword]))
    blob = io.BytesIO()
    ds.save_as(blob, enforce_file_format=False)
    return blob.getvalue()


def _byte_mutant(raw: bytes, rng: random.Random) -> bytes:
    b = bytearray(raw)
    kind = rng.randrange(5)
    if kind == 0:
        return bytes(b[:rng.randrange(len(b))])
    if kind == 1:
        for _ in range(rng.randint(1, 16)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == 2:
        at = rng.randrange(min(len(b), 600))  # damage near the header, where parsing happens
        b[at] = rng.randrange(256)
    elif kind == 3:
        at, size = rng.randrange(len(b)), rng.randint(1, 64)
        b[at:at] = bytes(b[at:at + size]) * rng.randint(2, 50)
    else:
        at = rng.randrange(len(b) + 1)
        b[at:at] = rng.choice([b"\x00", b"\xff\xfe", b"\n", b"\n\n", b"\r\n", b"=", b":"])
    return bytes(b)


def _mutant(name: str, files: dict, rng: random.Random) -> dict:
    raw = files[name]
    text_sep = {".mha": b"=", ".mhd": b"=", ".nrrd": b":", ".nhdr": b":"}.get(os.path.splitext(name)[1])
    structured = rng.random() < 0.7
    if structured and text_sep is not None:
        raw = _text_mutant(raw, rng, text_sep)
    elif structured and name.endswith(".nii"):
        raw = _nifti_mutant(raw, rng)
    elif structured and name.endswith(".nii.gz"):
        raw = gzip.compress(_nifti_mutant(gzip.decompress(raw), rng))
    elif structured and (name.endswith(".dcm") or name == "DICOMDIR"):
        try:
            raw = _dicom_mutant(raw, rng)
        except Exception:  # noqa: BLE001 - pydicom refused to write this value: damage the bytes instead
            raw = _byte_mutant(raw, rng)
    elif structured and name.endswith(".npy"):
        raw = _npy_mutant(raw, rng)
    elif structured and name.endswith(".npz"):
        with zipfile.ZipFile(io.BytesIO(raw)) as z:
            members = {n: z.read(n) for n in z.namelist()}
        key = rng.choice(sorted(members))
        members[key] = _npy_mutant(members[key], rng) if rng.random() < 0.7 else _byte_mutant(members[key], rng)
        blob = io.BytesIO()
        with zipfile.ZipFile(blob, "w", compression=rng.choice([zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])) as z:
            for n, content in members.items():
                z.writestr(n, content)
        raw = blob.getvalue()
    else:
        raw = _byte_mutant(raw, rng)
    return {**files, name: raw}


def _special_inputs(folder) -> list[str]:
    """Paths that are not regular files, or whose data file is not."""
    paths = []
    for name, target in (("zero.nrrd", "/dev/zero"), ("zero.mha", "/dev/zero"), ("null.nii", "/dev/null"),
                         ("passwd.npy", "/etc/passwd"), ("dangling.nii.gz", "/nonexistent/x")):
        os.symlink(target, folder / name)
        paths.append(str(folder / name))
    for name in ("pipe.nrrd", "pipe.mhd", "pipe.npy"):
        os.mkfifo(folder / name)
        paths.append(str(folder / name))
    os.mkfifo(folder / "pipe.raw")
    (folder / "fifo_data.mhd").write_text("NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n"
                                          "ElementDataFile = pipe.raw\n")
    (folder / "fifo_data.nhdr").write_text("NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"
                                           "data file: pipe.raw\n")
    os.symlink("/dev/zero", folder / "zero.raw")
    (folder / "zero_data.mhd").write_text("NDims = 3\nDimSize = 2 2 2\nElementType = MET_UCHAR\n"
                                          "ElementDataFile = zero.raw\n")
    paths += [str(folder / n) for n in ("fifo_data.mhd", "fifo_data.nhdr", "zero_data.mhd")]
    return paths


def _inputs(tmp_path) -> list[str]:
    rng = random.Random(SEED)
    seeds = _seeds(tmp_path)
    paths = []
    for s, (name, files) in enumerate(seeds):
        for k in range(PER_SEED):
            sub = tmp_path / f"m{s:02d}_{k:03d}"
            sub.mkdir()
            for n, content in _mutant(name, files, rng).items():
                (sub / n).parent.mkdir(parents=True, exist_ok=True)
                (sub / n).write_bytes(content)
            os.mkfifo(sub / "pipe.raw")  # a data-file name a mutant may pick: must not block
            paths.append(str(sub / name))
    return paths + _special_inputs(tmp_path)


def load_checked(path: str) -> None:
    """The child's reader: ``load``, and what a loaded volume must be (an AssertionError counts
    as a traceback): native-endian voxels of a deformable type, finite geometry."""
    vol = load(path)
    assert vol.data.ndim == 3 and vol.data.dtype in SUPPORTED_DTYPES and vol.data.dtype.isnative, vol
    assert np.all(np.isfinite(vol.spacing)) and np.all(vol.spacing > 0) and np.all(np.isfinite(vol.origin)), vol


@pytest.mark.filterwarnings("ignore")
def test_fuzz_volume_readers(tmp_path):
    paths = _inputs(tmp_path)
    assert len(paths) == 1271
    outcomes = run_reader("test_fuzz_volumes:load_checked", paths, timeout_s=10.0, env=CHILD_ENV)
    result = summary(outcomes, paths)
    print(result["counts"], result["seconds"], "s")
    assert result["n_bad"] == 0, result["bad"]
    assert result["n_unnamed"] == 0, result["unnamed"]
    assert result["counts"].get("clean", 0) > len(paths) // 2  # most mutants are refused, not ignored
