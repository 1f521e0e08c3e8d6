"""A corpus of hostile export zips, built in code from a real toy export: every one is refused by `rba replay` with
exit 2 and one printable line (no traceback, nothing simulated), by ``rba.gym.ExportedReward`` with the same message,
and the worst ones within bounded memory in a fresh process."""

from __future__ import annotations

import hashlib
import io
import json
import os
import struct
import subprocess
import sys
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from rba.cli import main
from rba.data.export_zip import ExportError
from rba.domains import get_domain
from rba.gym import ExportedReward

ROOT = Path(__file__).resolve().parents[1]
ESCAPE = "\x1b]0;owned\x07\x1b[2J\x1b[31m"  # sets the terminal's title, clears the screen, turns text red


@pytest.fixture(scope="module")
def good(toy_roots, tmp_path_factory) -> Path:
    """A real export of a toy serve rollout with a global reward (as `rba export` writes one)."""
    from rba.core.fileio import load_json
    from rba.data.export_zip import ExportSource, write_export
    from rba.data.library import SkillLibrary

    data, models, _ = toy_roots
    serve = SkillLibrary.load("toy", "serve", data)
    version = "-".join(load_json(models / "toy" / f"{kind}-onehot.json")["weights_sha"]
                       for kind in ("ranker", "global_reward"))
    rounds = [{"step": 0, "feedback": "satisfied", "rollout_before": serve.ids[5], "rollout_after": serve.ids[5]}]
    out = tmp_path_factory.mktemp("hostile") / "good.zip"
    write_export(out, ExportSource("toy", "global", "onehot", version, "builtin", models, serve, serve.ids[5],
                                   rounds, clip=b"\0\0\0\x20ftypisom"))
    return out


def _members_of(raw: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(raw)) as zf:
        return {n: zf.read(n) for n in zf.namelist()}


def _members(good: Path) -> dict[str, bytes]:
    return _members_of(good.read_bytes())


def _zip(members: dict[str, bytes] | list[tuple[str | zipfile.ZipInfo, bytes]],
         compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=compression) as zf, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "Duplicate name": one case writes a member twice on purpose
        for name, data in (members.items() if isinstance(members, dict) else members):
            zf.writestr(name, data)
    return out.getvalue()


def _export(good: Path, profile: Callable[[dict], dict] | None = None, card: Callable[[dict], dict] | None = None,
            weights: Callable[[dict], dict] | None = None, add: dict[str, bytes] | None = None,
            raw_profile: bytes | None = None, text: tuple[bytes, bytes] = (b"", b"")) -> bytes:
    """The good export edited (profile, reward card, state_dict, added members) with every sha256 made to match, so
    the reader's deeper checks are what refuse it."""
    members = _members(good)
    if card is not None:
        members["reward.json"] = json.dumps(card(json.loads(members["reward.json"]))).encode()
    if weights is not None:
        buf = io.BytesIO()
        torch.save(weights(torch.load(io.BytesIO(members["reward.pt"]), weights_only=True)), buf)
        members["reward.pt"] = buf.getvalue()
    members.update(add or {})
    p = json.loads(members["profile.json"])
    p["members"] = {n: hashlib.sha256(d).hexdigest() for n, d in members.items() if n != "profile.json"}
    edited = json.dumps((profile or dict)(p)).encode().replace(*text)
    members["profile.json"] = raw_profile if raw_profile is not None else edited
    return _zip(members)


def _patched(raw: bytes, name: str, **fields: int) -> bytes:
    """``raw`` with a member's header fields (``flags``, ``method``, ``size``: unpacked, ``mode``: unix mode bits)
    set in its central directory entry (what the listing says) and, where they exist, its local header."""
    central = {"flags": (8, "<H"), "method": (10, "<H"), "size": (24, "<I"), "mode": (38, "<I")}
    local = {"flags": (6, "<H"), "method": (8, "<H")}
    out, at = bytearray(raw), raw.find(b"PK\x01\x02")
    while at >= 0:
        length = struct.unpack_from("<H", raw, at + 28)[0]
        if raw[at + 46: at + 46 + length] == name.encode():
            header = struct.unpack_from("<I", raw, at + 42)[0]
            for key, value in fields.items():
                offset, fmt = central[key]
                struct.pack_into(fmt, out, at + offset, value << 16 if key == "mode" else value)
                if key in local:
                    struct.pack_into(local[key][1], out, header + local[key][0], value)
            return bytes(out)
        at = raw.find(b"PK\x01\x02", at + 1)
    raise AssertionError(f"no member {name}")


def _corrupt(raw: bytes, name: str) -> bytes:
    """``raw`` with a deflated member's compressed bytes overwritten (the listing unchanged)."""
    with zipfile.ZipFile(io.BytesIO(raw)) as zf:
        info = zf.getinfo(name)
    start = info.header_offset + 30 + len(info.filename) + struct.unpack_from("<H", raw, info.header_offset + 28)[0]
    junk = bytes(range(256)) * (info.compress_size // 256 + 1)
    return raw[:start] + junk[: info.compress_size] + raw[start + info.compress_size:]


def _npy(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, array, allow_pickle=allow_pickle)
    return buf.getvalue()


def _with_array(good: Path, data: bytes) -> bytes:
    """The good export with an ``anchor`` condition array (a global reward reads none, so only its checks see it)."""
    return _export(good, add={"anchor.npy": data},
                   profile=lambda p: {**p, "reward": {**p["reward"], "arrays": {"anchor": "anchor.npy"}}})


def _arch(**change) -> Callable[[dict], dict]:
    return lambda card: {**card, "architecture": {**card["architecture"], **change}}


def _huge_header_npy() -> bytes:
    """A .npy whose header claims 10**12 states of 4 floats over 32 bytes of data."""
    header = b"{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000000, 4), }"
    header += b" " * (63 - (10 + len(header)) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + b"\0" * 32


def _many_members() -> bytes:
    return _zip([(f"m{i}.npy", b"") for i in range(60_000)], zipfile.ZIP_STORED)


def _bomb(good: Path) -> bytes:
    members = _members(good)
    members["clip.mp4"] = bytes(50 << 20)  # 50 MiB of zeros deflate to 50 KB
    return _zip(members)


# case -> (the zip's bytes from the good export, a part of the one-line refusal)
CASES: dict[str, tuple[Callable[[Path], bytes], str]] = {
    # the six crashes
    "deeply nested profile": (lambda g: _export(g, raw_profile=b"[" * 200_000 + b"]" * 200_000),
                              "profile.json is nested too deeply"),
    "encrypted member": (lambda g: _patched(g.read_bytes(), "reward.json", flags=0x1),
                         "member reward.json is encrypted"),
    "unknown compression": (lambda g: _patched(g.read_bytes(), "reward.json", method=99),
                            "member reward.json uses compression method 99"),
    "corrupt deflate data": (lambda g: _corrupt(g.read_bytes(), "profile.json"), "the zip is truncated or corrupt"),
    "proxy 10**400": (lambda g: _export(g, lambda p: {**p, "proxies": {**p["proxies"], "pace": 10**400}}),
                      "profile.json proxies must map attribute names to finite numbers"),
    "NaN proxy": (lambda g: _export(g, lambda p: {**p, "proxies": {**p["proxies"], "pace": float("nan")}}),
                  "profile.json is not JSON ('NaN is not a JSON number')"),
    "proxy 1e999 (inf)": (lambda g: _export(g, lambda p: {**p, "proxies": {**p["proxies"], "pace": 123.25}},
                                            text=(b"123.25", b"1e999")),
                          "profile.json proxies must map attribute names to finite numbers"),
    # the reward's architecture
    "hidden 8000, 12 layers": (lambda g: _export(g, card=_arch(hidden=8000, layers=12)),
                               "reward.json architecture hidden must be an integer in [1, 2048], got 8000"),
    "hidden 32000": (lambda g: _export(g, card=_arch(hidden=32000)),
                     "reward.json architecture hidden must be an integer in [1, 2048], got 32000"),
    "300000 layers": (lambda g: _export(g, card=_arch(hidden=2, layers=300_000)),
                      "reward.json architecture layers must be an integer in [1, 8], got 300000"),
    "architecture beyond the parameter cap": (lambda g: _export(g, card=_arch(hidden=2048, layers=8)),
                                              "parameters; a reward has at most 8000000"),
    "architecture bigger than the weights": (lambda g: _export(g, card=_arch(hidden=1024)),
                                             "member reward.pt does not match reward.json's architecture"),
    "hidden as text": (lambda g: _export(g, card=_arch(hidden="64")),
                       "reward.json architecture hidden must be an integer in [1, 2048], got '64'"),
    "state_dim not the domain's": (lambda g: _export(g, card=_arch(state_dim=5)),
                                   "reward.json architecture state_dim 5 is not domain 'toy''s 4"),
    "tensor of another shape": (lambda g: _export(g, weights=lambda w: {**w, "f.0.bias": torch.zeros(65)}),
                                "tensor 'f.0.bias' is ((65,), torch.float32), expected ((64,), torch.float32)"),
    "float64 weights": (lambda g: _export(g, weights=lambda w: {k: v.double() for k, v in w.items()}),
                        "member reward.pt does not match reward.json's architecture"),
    "extra tensor": (lambda g: _export(g, weights=lambda w: {**w, "evil": torch.zeros(1)}),
                     "tensor 'evil' is ((1,), torch.float32), expected None"),
    "NaN weights": (lambda g: _export(g, weights=lambda w: {**w, "f.0.bias": torch.full((64,), float("nan"))}),
                    "member reward.pt holds NaN or infinite values"),
    "weights not tensors": (lambda g: _export(g, weights=lambda w: {"w": 1}),
                            "member reward.pt must be a state_dict: tensors by name"),
    "deflated weight records": (lambda g: _export(g, add={"reward.pt": _zip(_members_of(_members(g)["reward.pt"]))}),
                                "member reward.pt is not a torch state_dict archive as torch.save writes one"),
    # strings that would be printed
    "escape sequences in the rollout id": (lambda g: _export(g, lambda p: {**p, "rollout_id": f"serve-1{ESCAPE}"}),
                                           "rollout id 'serve-1\\x1b]0;owned\\x07"),
    "a rollout id no export names": (lambda g: _export(g, lambda p: {**p, "rollout_id": "my favourite"}),
                                     "rollout id 'my favourite' is none an export names"),
    "escape sequences in a simulator version": (
        lambda g: _export(g, lambda p: {**p, "simulators": {"mujoco": ESCAPE}}),
        "profile.json simulator version must be printable text of at most 200 characters, got '\\x1b]0;"),
    "escape sequences in a member name": (lambda g: _zip({**_members(g), f"{ESCAPE}.npy": b""}),
                                          "member '\\x1b]0;owned\\x07"),
    "escape sequences in an unknown domain": (lambda g: _export(g, lambda p: {**p, "domain": ESCAPE}),
                                              "unknown domain '\\x1b]0;owned"),
    "a long reward note": (lambda g: _export(g, lambda p: {**p, "reward_note": "x" * 1500}),
                           "profile.json reward_note must be printable text of at most 1000 characters, got 'xxx"),
    # more of the kind
    "zip bomb by ratio": (_bomb, "times: a zip bomb, not an RBA export"),
    "60000 members": (lambda g: _many_members(), "lists 60000 members"),
    "duplicate profile": (lambda g: _zip([("profile.json", b"{}"), *_members(g).items()]),
                          "member profile.json appears more than once"),
    "path-like name": (lambda g: _zip({**_members(g), "../../etc/profile.json": b""}),
                       "member '../../etc/profile.json' is no export member"),
    "absolute name": (lambda g: _zip({**_members(g), "/tmp/x.npy": b""}), "member '/tmp/x.npy' is no export member"),
    "folder entry": (lambda g: _zip({**_members(g), "reward/": b""}), "member 'reward/' is no export member"),
    "member beyond its size cap": (lambda g: _patched(g.read_bytes(), "reward.json", size=5 << 20),
                                   "member reward.json unpacks to more than 4 MiB"),
    "symlink member": (lambda g: _patched(g.read_bytes(), "reward.json", mode=0o120777),
                       "member reward.json is not a plain file (a link or device)"),
    "bad UTF-8 profile": (lambda g: _export(g, raw_profile=b'{"format": "\xff\xfe"}'),
                          "profile.json is not UTF-8 text"),
    "integer of 5000 digits": (lambda g: _export(g, raw_profile=b'{"seed": ' + b"9" * 5000 + b"}"),
                               "profile.json is not JSON ("),
    "profile beyond the JSON cap": (lambda g: _export(g, lambda p: {**p, "feedback": [0] * 1_500_000}),
                                    "member profile.json unpacks to more than 4 MiB"),
    "feedback of numbers": (lambda g: _export(g, lambda p: {**p, "feedback": [0] * 100_000}),
                            "profile.json feedback must be a list of rounds (objects)"),
    "object array": (lambda g: _with_array(g, _npy(np.array([{"a": 1}], dtype=object), allow_pickle=True)),
                     "member anchor.npy must hold 1 to 10000 states"),
    "integer array": (lambda g: _with_array(g, _npy(np.zeros((3, 4), np.int64))),
                      "member anchor.npy must hold 1 to 10000 states of 4 float32 or float64 values"),
    "3-D array": (lambda g: _with_array(g, _npy(np.zeros((3, 4, 1), np.float32))),
                  "it holds (3, 4, 1) of 'float32'"),
    "array header claiming 10**12 states": (lambda g: _with_array(g, _huge_header_npy()),
                                            "it holds (1000000000000, 4) of 'float32'"),
    "NaN array": (lambda g: _with_array(g, _npy(np.full((3, 4), np.nan, np.float32))),
                  "member anchor.npy holds NaN or infinite values"),
    "unknown method": (lambda g: _export(g, lambda p: {**p, "method": "magic"}), "unknown method 'magic'; valid: "),
    "member sha not hex": (lambda g: _export(g, lambda p: {**p, "members": {**p["members"], "clip.mp4": "x"}}),
                           "profile.json members must map names to sha256 (64 hex digits); clip.mp4's is 'x'"),
    "truncated zip": (lambda g: g.read_bytes()[: len(g.read_bytes()) - 30], "is not a zip archive"),
    "not a zip": (lambda g: b"#!/bin/sh\nrm -rf /\n", "is not a zip archive"),
    "reward.pt not a zip": (lambda g: _export(g, add={"reward.pt": b"hello"}),
                            "member reward.pt is not a zip archive"),
}


def _written(good: Path, case: str, tmp_path: Path) -> Path:
    path = tmp_path / f"{case.replace(' ', '_').replace('*', '')}.zip"
    path.write_bytes(CASES[case][0](good))
    return path


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_zip_is_refused_in_one_printable_line(good, case, tmp_path, capsys, monkeypatch):
    """`rba replay` exits 2 with one line and simulates nothing; ExportedReward refuses with the same message."""
    path = _written(good, case, tmp_path)

    def refuse(*args, **kwargs):
        raise AssertionError("simulated before every check passed")

    monkeypatch.setattr(type(get_domain("toy")), "rollout", refuse)
    assert main(["replay", str(path)]) == 2
    captured = capsys.readouterr()
    message = captured.err.removeprefix("rba: error: ").removesuffix("\n")
    assert captured.out == "" and captured.err == f"rba: error: {message}\n"
    assert CASES[case][1] in message, message
    assert message.isprintable() and len(message) < 400
    with pytest.raises(ExportError) as refused:
        ExportedReward(path)
    assert str(refused.value) == message


def test_the_good_export_is_read_and_replayed(good, capsys):
    """The corpus's source is a valid export: what refuses the cases is their edit."""
    assert main(["replay", str(good)]) == 0
    assert capsys.readouterr().out.strip().endswith("match")
    reward = ExportedReward(good).export.reward
    assert reward is not None and np.isfinite(reward.total(np.zeros((3, 4))))


@pytest.mark.parametrize("case", ["hidden 8000, 12 layers", "hidden 32000", "300000 layers", "zip bomb by ratio",
                                  "60000 members", "deeply nested profile", "array header claiming 10**12 states"])
def test_the_worst_zips_are_refused_in_bounded_memory(good, case, tmp_path):
    """A fresh `rba replay` process refuses each within a generous timeout and peaks under 1.5 GB (the issue's cases
    reached 2.7 GB, asked for 41 GB or hung); `pytest -s` prints each peak."""
    path = _written(good, case, tmp_path)
    # the peak is VmHWM (this process image's own, in KiB): ru_maxrss keeps a forking parent's across exec, and
    # pytest's process is large by then
    script = ("import re, sys\nfrom rba.domains import register\nregister('toy', 'tests.toy:Toy')\n"
              "from rba.cli import main\ncode = main(['replay', sys.argv[1]])\n"
              "status = open('/proc/self/status').read()\n"
              "print(re.search(r'VmHWM:\\s+(\\d+) kB', status).group(1), file=sys.stderr)\nsys.exit(code)\n")
    env = {**os.environ, "MUJOCO_GL": "egl", "SDL_VIDEODRIVER": "offscreen", "HF_HUB_OFFLINE": "1"}
    done = subprocess.run([sys.executable, "-c", script, str(path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 2 and lines[0].startswith("rba: error: "), done.stderr
    assert CASES[case][1] in lines[0]
    print(f"{case}: peak {int(lines[1]) >> 10} MiB")  # pytest -s shows them
    assert int(lines[1]) < 1_500_000, f"peak {int(lines[1]) >> 10} MiB"
