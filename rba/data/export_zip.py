"""Take a tuned behaviour away: the export zip of a satisfied session, read back without unpickling.

A zip holds ``profile.json`` (what was chosen and how: domain, targets, feedback, models, skill
parameters and seed, simulator versions; the sha256 of every other member), ``clip.mp4`` and, when
the method has a reward to condition on the choice, ``reward.pt`` (a state_dict, ``torch.save`` of
tensors only, read with ``weights_only=True``) + ``reward.json`` (its model card) and the condition's
arrays as ``.npy`` (``allow_pickle=False``). docs/architecture.md §4 (Export) says what each method exports:

* a reward of kind ``global_reward`` (RBA-Global): rθ(s | v*) with v* the ranker's ζσ score of the
  chosen rollout, standardised as the model expects (``condition.v_star``; ``condition.zeta`` raw), its
  last layer re-fitted for that v* on the library's ζσ ranking (``refit_for_target``; the card's
  ``refit`` says from which weights and how) where the domain chooses it (``Domain.export_refit``; the walker
  exports its trained weights) unless the source says otherwise;
* ``local_reward`` (RBA-Local): rθ(s | α, h, φ(anchor)) of the last round that asked for a change: the
  anchor is the clip that round answered about (``anchor.npy``, its states), the reward the mean over
  that round's changes (α, h). A session satisfied with its first clip asked for none: no reward.

Everything is keyed on the rollout's params + seed (``Domain.rollout`` replays it exactly), never on
library membership. ``read_export`` is the one reader (``rba replay``, ``rba.gym``).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import io
import json
import math
import re
import stat
import struct
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from rba.core.artifacts import BUILDERS, ModelNotFoundError, load_model, weights_sha
from rba.core.fileio import write_atomic
from rba.core.methods import get_method, method_names
from rba.data.library import SPLITS, SkillLibrary
from rba.domains import Domain, Rollout, domain_names, get_domain
from rba.generate.cma import ID_PREFIX
from rba.learn.common import Ragged
from rba.learn.global_reward import RefitConfig, refit_for_target

FORMAT = "rba-export"
FORMAT_VERSION = 1
PROFILE, CLIP, REWARD_WEIGHTS, REWARD_CARD, README = (
    "profile.json", "clip.mp4", "reward.pt", "reward.json", "README.md")
SIMULATORS = ("mujoco", "dm-control", "highway-env", "gymnasium")  # package versions a replay depends on
PICKLE_PROTOCOL_MARK = b"\x80"  # every pickle of protocol 2+ starts with the PROTO opcode
DOMAIN_REFIT = "domain"  # ExportSource.refit: as the domain chooses
REPLAY_RTOL, REPLAY_ATOL = 1e-6, 1e-9  # a replayed proxy "matches" within these (same packages: bit-exact)
SEED_BITS = 32  # a profile's seed is below 2**SEED_BITS: every domain's generator takes it (library seeds < 4e6)
# What a read accepts, checked before anything is unpacked or built (docs/decisions/0023-export-read-caps.md).
MAX_MEMBER_BYTES = 64 << 20  # a member's size, unpacked: a clip is a few MB, a reward's weights under one
MAX_EXPORT_BYTES = 256 << 20  # all members, unpacked: read into memory, so a small zip may not unpack to GBs
MAX_JSON_BYTES = 4 << 20  # a JSON member, unpacked: a profile of thousands of feedback rounds is under 1 MiB
MAX_RATIO = 100  # unpacked / packed bytes beyond MAX_RATIO_FLOOR: a clip and weights hardly compress
MAX_RATIO_FLOOR = 1 << 20  # an export unpacking to less is never refused for its ratio
MAX_MEMBERS = 16  # profile, clip, README, reward weights and card, a few condition arrays
END_RECORD_SPAN = (1 << 16) + 22  # a zip's end record is in its last 22 bytes and a comment of up to 64 KiB
MAX_TEXT = 200  # a name or version from the zip (a reward note: 5 times this)
MAX_WEIGHT_RECORDS = 128  # records of reward.pt (a zip itself): one per tensor and a few torch bookkeeping ones
MAX_PICKLE_BYTES = 1 << 20  # reward.pt's data.pkl, the state_dict's structure (a few KB: names, shapes)
MAX_ANCHOR_STATES = 10_000  # states of an anchor clip: 100 times the longest shipped rollout's
MAX_REWARD_PARAMS = 8_000_000  # tensors' elements in a reward: 4x a paper-sized local reward (hidden 1024)
ARCHITECTURE_CAPS = {  # the largest value read per architecture field; our presets train at most a quarter
    "state_dim": 4096, "num_attributes": 64, "embed_dim": 1024, "hidden": 2048, "layers": 8, "lstm_hidden": 512,
    "lstm_layers": 4, "anchor_stride": 64}
MEMBER_NAME = re.compile(r"profile\.json|clip\.mp4|reward\.pt|reward\.json|README\.md|[a-z][a-z0-9_]{0,31}\.npy")
ROLLOUT_ID = re.compile(rf"(?:{'|'.join(SPLITS)})-[0-9]{{5,9}}|{ID_PREFIX}[0-9a-f]{{16}}")  # library and made ids
SHA256 = re.compile(r"[0-9a-f]{64}")


class ExportError(ValueError):
    """An export that cannot be made or read; the message is one line naming what is wrong."""


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _finite(value: Any) -> bool:
    """A JSON number a float holds: not NaN or ±inf, and no integer beyond float's range (10**400)."""
    try:
        return _is_number(value) and math.isfinite(value)
    except OverflowError:
        return False


def shown(value: Any, limit: int = 60) -> str:
    """``value`` as it may be printed: repr-escaped (no control characters reach a terminal), cut at ``limit``."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _text(value: Any, what: str, limit: int = MAX_TEXT) -> str:
    """``value`` if it is printable text of at most ``limit`` characters (it may be printed as it is)."""
    if not (isinstance(value, str) and len(value) <= limit and value.isprintable()):
        raise ExportError(f"{what} must be printable text of at most {limit} characters, got {shown(value)}")
    return value


def _numbers(values: Any, what: str, names: Any = None) -> None:
    """``values`` maps text (``names`` exactly, when given) to finite numbers."""
    if not isinstance(values, dict) or not all(_finite(v) for v in values.values()):
        raise ExportError(f"{what} must map attribute names to finite numbers")
    for name in values:
        _text(name, f"{what} name")
    if names is not None and sorted(values) != sorted(names):
        raise ExportError(f"{what} {sorted(values)} are not the attributes {list(names)}")


@dataclass(frozen=True)
class Profile:
    """``profile.json``: the chosen behaviour and everything needed to reproduce and reuse it."""

    domain: str
    method: str
    rep: str
    rollout_id: str
    params: dict[str, float]  # skill parameters, names -> values (the domain's param_names)
    seed: int
    proxies: dict[str, float]  # attribute targets in proxy units: the chosen clip's measured proxies
    zeta: dict[str, float] | None  # the same in ζσ units (the ranker's score), when the method has a ranker
    feedback: list[dict[str, Any]]  # every round: step, feedback ([{attribute, direction}] or "satisfied"), clips
    model: dict[str, Any]  # version, model_set, and per kind the card's weights_sha
    reward: dict[str, Any] | None  # kind, rep, condition (JSON), arrays (member names); None: no reward exported
    reward_note: str  # what the reward is, or why there is none
    simulators: dict[str, str | None]
    rba_version: str
    members: dict[str, str] = field(default_factory=dict)  # every other member -> its sha256
    format: str = FORMAT
    format_version: int = FORMAT_VERSION

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, obj: Any) -> Profile:
        """A profile from parsed JSON; ``ExportError`` naming the first problem (foreign or other-version files)."""
        if not isinstance(obj, dict):
            raise ExportError(f"{PROFILE} is not a JSON object")
        if obj.get("format") != FORMAT:
            raise ExportError(f"{PROFILE} is not an RBA export (format {obj.get('format')!r}, expected {FORMAT!r})")
        if obj.get("format_version") != FORMAT_VERSION:
            raise ExportError(f"unsupported format version {obj.get('format_version')!r}; this rba reads "
                              f"version {FORMAT_VERSION}")
        names = {f for f in cls.__dataclass_fields__}
        missing, unknown = sorted(names - set(obj)), sorted(set(obj) - names)
        if missing or unknown:
            raise ExportError(f"{PROFILE} fields do not match format {FORMAT_VERSION}: missing {missing}, "
                              f"unknown {unknown}")
        profile = cls(**obj)
        domain = profile.check_domain()
        _numbers(profile.proxies, f"{PROFILE} proxies", domain.attribute_names)
        if profile.zeta is not None:
            _numbers(profile.zeta, f"{PROFILE} zeta")
        profile._check_fields()
        return profile

    def _check_fields(self) -> None:
        """Every other field has the type ``export_bytes`` writes, and text that is printed is printable."""
        if self.method not in method_names():
            raise ExportError(f"unknown method {shown(self.method)}; valid: {', '.join(method_names())}")
        _text(self.rep, f"{PROFILE} rep")
        if not (isinstance(self.rollout_id, str) and ROLLOUT_ID.fullmatch(self.rollout_id)):
            raise ExportError(f"rollout id {shown(self.rollout_id)} is none an export names: a library's "
                              f"(<split>-<number>, e.g. serve-00042) or a made one ({ID_PREFIX}<16 hex digits>)")
        if not (isinstance(self.feedback, list) and all(isinstance(r, dict) for r in self.feedback)):
            raise ExportError(f"{PROFILE} feedback must be a list of rounds (objects)")
        if not isinstance(self.model, dict) or not (self.reward is None or isinstance(self.reward, dict)):
            raise ExportError(f"{PROFILE} model must be an object and reward null or an object")
        _text(self.reward_note, f"{PROFILE} reward_note", 5 * MAX_TEXT)
        _text(self.rba_version, f"{PROFILE} rba_version")
        if not isinstance(self.simulators, dict):
            raise ExportError(f"{PROFILE} simulators must map package names to versions")
        for name, version in self.simulators.items():
            _text(name, f"{PROFILE} simulator name")
            if version is not None:
                _text(version, f"{PROFILE} simulator version")
        if not isinstance(self.members, dict) or len(self.members) > MAX_MEMBERS:
            raise ExportError(f"{PROFILE} members must map at most {MAX_MEMBERS} member names to sha256")
        for name, sha in self.members.items():
            if not MEMBER_NAME.fullmatch(name) or name == PROFILE:
                raise ExportError(f"{PROFILE} members names {shown(name)}, which is no export member")
            if not (isinstance(sha, str) and SHA256.fullmatch(sha)):
                raise ExportError(f"{PROFILE} members must map names to sha256 (64 hex digits); {name}'s is "
                                  f"{shown(sha)}")

    def check_domain(self) -> Domain:
        """The profile's domain, if registered and its params are exactly the domain's ``param_names``."""
        if not isinstance(self.domain, str) or self.domain not in domain_names():
            raise ExportError(f"unknown domain {shown(self.domain)}; valid: {', '.join(domain_names())}")
        domain = get_domain(self.domain)
        if not isinstance(self.params, dict) or sorted(self.params) != sorted(domain.param_names):
            given = sorted(self.params) if isinstance(self.params, dict) else self.params
            raise ExportError(f"params {shown(given)} do not match domain {self.domain!r}'s param_names "
                              f"{list(domain.param_names)}")
        if not all(_is_number(v) for v in self.params.values()):
            raise ExportError("params must be numbers")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or not 0 <= self.seed < 2**SEED_BITS:
            raise ExportError(f"seed must be an integer in [0, 2**{SEED_BITS}), got {shown(self.seed)}")
        space = domain.param_space()
        if outside := space.outside(self.params):
            name = outside[0]
            raise ExportError(f"param {name} = {shown(self.params[name])} is outside domain {self.domain!r}'s range "
                              f"[{space.low[name]:g}, {space.high[name]:g}]")
        return domain


# -- making an export ---------------------------------------------------------------------------

@dataclass(frozen=True)
class ExportSource:
    """What a finished session gives: the app (``server.ops.session_export``) or a script fills it in."""

    domain: str
    method: str
    rep: str
    model_version: str  # the session's (it must still be what the model files hold)
    model_set: str
    models_root: Path
    library: SkillLibrary  # where the chosen rollout and the anchors are
    rollout_id: str
    feedback: list[dict[str, Any]]  # rounds in step order: step, feedback, rollout_before, rollout_after
    clip: bytes  # the chosen clip's MP4
    rollout: Rollout | None = None  # the chosen rollout when no library holds it (a generated one), else None
    # how a global reward's last layer is re-fitted for v*: None the trained weights, DOMAIN_REFIT as the domain
    # chooses (``Domain.export_refit``: RefitConfig() or None)
    refit: RefitConfig | Literal["domain"] | None = DOMAIN_REFIT

    def refit_config(self) -> RefitConfig | None:
        """The re-fit this export makes, if any (``refit`` resolved for the domain)."""
        if self.refit != DOMAIN_REFIT:
            return self.refit
        return RefitConfig() if get_domain(self.domain).export_refit else None


@dataclass(frozen=True)
class RewardPart:
    """The reward member of an export: weights, card, condition (JSON) and the condition's arrays."""

    kind: str
    weights: dict[str, torch.Tensor]
    card: dict[str, Any]
    condition: dict[str, Any]
    arrays: dict[str, np.ndarray]


def _states(library: SkillLibrary, rollout_id: str) -> np.ndarray:
    return library.trajectory(library.index_of(rollout_id))


def _global_condition(src: ExportSource, reward: Any, zeta: np.ndarray | None) -> tuple[dict, dict] | str:
    if zeta is None:
        return "a global reward needs the ranker's ζσ of the chosen rollout"
    with torch.no_grad():
        v = reward.model.zeta_norm(torch.as_tensor(zeta, dtype=torch.float32)).tolist()
    return {"zeta": [float(z) for z in zeta], "v_star": v}, {}


def _local_condition(src: ExportSource, reward: Any, zeta: np.ndarray | None) -> tuple[dict, dict] | str:
    asked = [r for r in src.feedback if isinstance(r["feedback"], list) and r["feedback"]]
    if not asked:
        return "RBA-Local conditions its reward on an asked change; this session was satisfied with its first clip"
    last, names = asked[-1], [a["name"] for a in reward.card["attributes"]]
    changes = [{"attribute": c["attribute"], "direction": 1 if c["direction"] == "more" else -1}
               for c in last["feedback"]]
    unknown = [c["attribute"] for c in changes if c["attribute"] not in names]
    if unknown:
        return f"the local reward knows no attribute {unknown[0]!r}; it knows {', '.join(names)}"
    return ({"anchor_rollout": last["rollout_before"], "changes": changes},
            {"anchor": _states(src.library, last["rollout_before"])})


# reward kind -> its condition for the chosen behaviour: (condition JSON, arrays) or why there is none
CONDITIONS: dict[str, Callable[[ExportSource, Any, np.ndarray | None], tuple[dict, dict] | str]] = {
    "global_reward": _global_condition,
    "local_reward": _local_condition,
}
REWARD_NOTES = {
    "global_reward": "rθ(s | v*) per state; v* = condition.v_star, the ranker's ζσ of the chosen rollout "
                     "standardised by the model's zeta_norm",
    "local_reward": "rθ(s | α, h, φ(anchor)) per state, the mean over condition.changes; anchor = anchor.npy, "
                    "the states of the clip the last asking round answered about",
}


def _refit(src: ExportSource, arts: dict[str, Any], target_zeta: np.ndarray, card: dict,
           cfg: RefitConfig) -> tuple[torch.nn.Module, dict]:
    """rθ with its last layer re-fitted for v* = ``target_zeta`` on the library's ζσ (the labels it was trained
    on); the card's ``held_out`` and ``tuning`` stay those of the trained weights, as ``refit`` says."""
    data = Ragged.from_numpy(src.library.states, src.library.state_offsets)
    model, info = refit_for_target(arts["global_reward"].model, data, arts["ranker"].model.score(data), target_zeta,
                                   cfg)
    info = {"from_weights_sha": card["weights_sha"], "library": src.library.split, **info,
            "note": "held_out and tuning describe the trained weights (from_weights_sha)"}
    return model, {**card, "weights_sha": weights_sha(model), "refit": info}


# reward kind -> how its weights are re-fitted for the chosen behaviour (when ``ExportSource.refit`` is set)
REFITS: dict[str, Callable[[ExportSource, dict[str, Any], np.ndarray, dict, RefitConfig],
                           tuple[torch.nn.Module, dict]]] = {
    "global_reward": _refit,
}


def _versions() -> tuple[dict[str, str | None], str]:
    def version(name: str) -> str | None:
        try:
            return importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            return None

    return {name: version(name) for name in SIMULATORS}, version("rba-studio") or "unknown"


def build_export(src: ExportSource) -> tuple[Profile, RewardPart | None]:
    """The profile and reward of a finished session; ``ExportError`` if its models are no longer the session's."""
    method = get_method(src.method)
    try:
        arts = {kind: load_model(src.domain, kind, src.rep, src.models_root) for kind in method.model_kinds}
    except ModelNotFoundError as exc:
        raise ExportError(f"the models of set {src.model_set!r} this session used are gone ({exc})") from None
    stale = [k for k, a in arts.items() if a.card["weights_sha"] not in src.model_version.split("-")]
    if stale:
        raise ExportError(f"the {', '.join(stale)} model of set {src.model_set!r} is no longer the one session "
                          f"model {src.model_version} used; it cannot be exported")
    chosen = src.rollout or src.library.rollout(src.library.index_of(src.rollout_id))
    states = chosen.states
    zeta = None
    if "ranker" in arts:
        zeta = arts["ranker"].model.score(Ragged.from_numpy(states, np.array([0, len(states)])))[0]
    reward, note = None, f"{method.label} exports no reward model"
    kind = next((k for k in method.model_kinds if k in CONDITIONS), None)
    if kind is not None:
        made = CONDITIONS[kind](src, arts[kind], zeta)
        if isinstance(made, str):
            note = made
        else:
            model, card = arts[kind].model, arts[kind].card
            refit = src.refit_config() if kind in REFITS else None
            if refit is not None:
                model, card = REFITS[kind](src, arts, zeta, card, refit)
            reward = RewardPart(kind, model.state_dict(), card, *made)
            note = REWARD_NOTES[kind]
    simulators, rba_version = _versions()
    attrs = [a["name"] for a in arts["ranker"].card["attributes"]] if "ranker" in arts else []  # admins' too
    profile = Profile(
        domain=src.domain, method=src.method, rep=src.rep, rollout_id=src.rollout_id,
        params={k: float(v) for k, v in chosen.params.items()}, seed=int(chosen.seed),
        proxies={k: float(v) for k, v in chosen.proxies.items()},
        zeta=None if zeta is None else dict(zip(attrs, map(float, zeta), strict=True)),
        feedback=src.feedback,
        model={"version": src.model_version, "model_set": src.model_set,
               "weights_sha": {k: a.card["weights_sha"] for k, a in arts.items()}},
        reward=None if reward is None else {"kind": reward.kind, "rep": src.rep, "condition": reward.condition,
                                            "arrays": {name: f"{name}.npy" for name in reward.arrays}},
        reward_note=note, simulators=simulators, rba_version=rba_version)
    return profile, reward


def _npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asarray(array), allow_pickle=False)
    return buf.getvalue()


MEMBER_NOTES = {  # what each member is, for the README inside every export
    README: "this file",
    PROFILE: "the chosen behaviour: domain, method, the skill's params and seed, its measured attributes (proxies) "
             "and ζσ scores, every feedback round, the model and simulator versions, and the sha256 of every other "
             "member (the reader checks them)",
    CLIP: "the chosen behaviour's video (H.264 MP4)",
    REWARD_WEIGHTS: "the reward model rθ: a torch state_dict of tensors only; load it with "
                    "`torch.load(f, weights_only=True)`",
    REWARD_CARD: "the reward model's card: its architecture (to rebuild it), attributes and training record",
}
ARRAY_NOTE = "an array the reward is conditioned on (profile.json's reward.arrays); `numpy.load(f, allow_pickle=False)`"


def _readme(profile: Profile, names: list[str]) -> bytes:
    """``README.md``: what each of ``names`` (the zip's members) is and how to use the export."""
    lines = [f"# RBA Studio export: {profile.domain} behaviour {profile.rollout_id}", "",
             f"A behaviour chosen in RBA Studio with {profile.method} ({FORMAT} format version {FORMAT_VERSION}). "
             "Nothing needs unpacking: the tools below read the zip itself.", "", "## Members", ""]
    lines += [f"- `{name}`: {MEMBER_NOTES.get(name, ARRAY_NOTE)}" for name in names]
    lines += ["", "## Use", "",
              "- `rba replay <this zip>` simulates the behaviour again from its params and seed and compares its "
              "attributes with the profile's (exit 0: they match; 1: they differ; 2: not a valid export).",
              "- `rba.gym.skill_policy(\"<this zip>\")` is the scripted skill with these params as a policy for the "
              f"domain's Gymnasium env, `gymnasium.make(rba.gym.env_id(\"{profile.domain}\"))`."]
    if REWARD_WEIGHTS in names:
        lines.append("- `rba.gym.ExportedReward(\"<this zip>\")` wraps that env so its reward is rθ on each state: "
                     f"{profile.reward_note}.")
    else:
        lines.append(f"- No reward model: {profile.reward_note}.")
    return ("\n".join(lines) + "\n").encode()


def export_bytes(profile: Profile, reward: RewardPart | None, clip: bytes) -> bytes:
    """The zip's bytes: a README, every member, then ``profile.json`` naming each one's sha256."""
    members = {CLIP: clip}
    if reward is not None:
        weights = io.BytesIO()
        torch.save({k: v.detach().cpu() for k, v in reward.weights.items()}, weights)
        members[REWARD_WEIGHTS] = weights.getvalue()
        members[REWARD_CARD] = json.dumps(reward.card, indent=2, sort_keys=True).encode()
        members.update({f"{name}.npy": _npy(a) for name, a in reward.arrays.items()})
    members = {README: _readme(profile, [README, PROFILE, *members]), **members}
    hashes = {name: hashlib.sha256(data).hexdigest() for name, data in members.items()}
    profile = Profile(**{**profile.to_json(), "members": hashes})
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(PROFILE, json.dumps(profile.to_json(), indent=2) + "\n")
        for name, data in members.items():
            zf.writestr(name, data, compress_type=zipfile.ZIP_STORED if name == CLIP else zipfile.ZIP_DEFLATED)
    return out.getvalue()


def write_export(path: Path, src: ExportSource) -> Profile:
    """Build the export of ``src`` and write it to ``path`` atomically (temporary file, then rename)."""
    if Path(path).is_dir():
        raise ExportError(f"{path} is a folder; give the zip's file path, e.g. {Path(path) / 'behaviour.zip'}")
    profile, reward = build_export(src)
    data = export_bytes(profile, reward, src.clip)
    write_atomic(Path(path), lambda tmp: Path(tmp).write_bytes(data))
    return profile


# -- reading one back ---------------------------------------------------------------------------

class ExportedRewardModel:
    """rθ of an export, conditioned as the export says: ``rewards(states float[T, D]) -> float64[T]``."""

    def __init__(self, kind: str, model: torch.nn.Module, card: dict, condition: dict,
                 arrays: dict[str, np.ndarray]) -> None:
        self.kind, self.model, self.card = kind, model.eval(), card
        self.condition, self.arrays = condition, arrays
        self.state_dim = int(card["architecture"]["state_dim"])
        self._conditions = self._local_conditions() if kind == "local_reward" else []

    @torch.no_grad()
    def _local_conditions(self) -> list[torch.Tensor]:
        """A local reward's condition per asked change, encoded once (the anchor's φ): an env step then costs
        one forward pass per change."""
        anchor = np.asarray(self.arrays["anchor"], dtype=np.float32)
        phi = self.model.encode(Ragged.from_numpy(anchor, np.array([0, len(anchor)])), torch.tensor([0]))
        names = [a["name"] for a in self.card["attributes"]]
        return [self.model.condition(phi, torch.tensor([names.index(c["attribute"])]), torch.tensor([c["direction"]]))
                for c in self.condition["changes"]]

    @torch.no_grad()
    def rewards(self, states: np.ndarray) -> np.ndarray:
        s = torch.as_tensor(np.asarray(states, dtype=np.float32).reshape(-1, self.state_dim))
        if self.kind == "global_reward":
            v = torch.tensor(self.condition["v_star"], dtype=torch.float32).expand(len(s), -1)
            return self.model(s, v).double().numpy()
        out = sum(self.model(s, cond, torch.zeros(len(s), dtype=torch.int64)) for cond in self._conditions)
        return (out / len(self._conditions)).double().numpy()

    def total(self, states: np.ndarray) -> float:
        """Σ_t rθ(s_t | condition): a rollout's return, the quantity the method ranks behaviours by."""
        return float(self.rewards(states).sum())


@dataclass(frozen=True)
class Export:
    """A read export: the profile, the clip's bytes and (when exported) the conditioned reward."""

    profile: Profile
    clip: bytes
    reward: ExportedRewardModel | None


def _check_directory(tail: bytes, what: str, max_entries: int) -> None:
    """The end record in a zip's ``tail`` (its last 64 KiB + 22 bytes) names at most ``max_entries`` members in a
    small listing; read before ``ZipFile`` parses the listing (a million empty members would cost it gigabytes)."""
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or len(tail) < at + 22:
        raise ExportError(f"{what} is not a zip archive (truncated or not an export)")
    entries, directory = struct.unpack("<HI", tail[at + 10: at + 16])
    if entries > max_entries or directory > max_entries * 1024:
        raise ExportError(f"{what} lists {entries} members in {directory} bytes; an export's holds at most "
                          f"{max_entries} members in {max_entries * 1024} bytes")


def _tail(path: Path) -> bytes:
    with path.open("rb") as f:
        f.seek(max(0, path.stat().st_size - END_RECORD_SPAN))
        return f.read()


def _check_info(info: zipfile.ZipInfo) -> None:
    """A member as ``export_bytes`` writes it: a known name, a plain file, stored or deflated, not encrypted, and a
    size of its kind."""
    name = info.filename
    if not MEMBER_NAME.fullmatch(name):
        raise ExportError(f"member {shown(name)} is no export member (valid: {PROFILE}, {CLIP}, {README}, "
                          f"{REWARD_WEIGHTS}, {REWARD_CARD}, <name>.npy)")
    if info.flag_bits & 0x1:
        raise ExportError(f"member {name} is encrypted; exports are not")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise ExportError(f"member {name} uses compression method {info.compress_type}; exports are stored or "
                          "deflated")
    kind = stat.S_IFMT(info.external_attr >> 16)
    if kind not in (0, stat.S_IFREG):
        raise ExportError(f"member {name} is not a plain file (a link or device); exports hold files only")
    cap = MAX_JSON_BYTES if name.endswith((".json", ".md")) else MAX_MEMBER_BYTES
    if info.file_size > cap:
        raise ExportError(f"member {name} unpacks to more than {cap >> 20} MiB; not an RBA export")


def _check_listing(infos: list[zipfile.ZipInfo], packed: int) -> None:
    """Each member once, each one an export's, and sizes an export has, before anything is unpacked."""
    if len(infos) > MAX_MEMBERS:
        raise ExportError(f"the zip holds {len(infos)} members; an export has at most {MAX_MEMBERS}")
    for info in infos:
        _check_info(info)
    if twice := sorted(n for n, k in Counter(info.filename for info in infos).items() if k > 1):
        raise ExportError(f"member {twice[0]} appears more than once; an export holds each member once")
    unpacked = sum(i.file_size for i in infos)
    if unpacked > MAX_EXPORT_BYTES:
        raise ExportError(f"the members unpack to more than {MAX_EXPORT_BYTES >> 20} MiB; not an RBA export")
    if unpacked > max(MAX_RATIO * packed, MAX_RATIO_FLOOR):
        raise ExportError(f"the members unpack to {unpacked} bytes from a {packed}-byte zip, more than {MAX_RATIO} "
                          "times: a zip bomb, not an RBA export")


def _members(zf: zipfile.ZipFile, packed: int) -> dict[str, bytes]:
    _check_listing(zf.infolist(), packed)
    try:  # each read stops at the listed size and checks the CRC
        data = {info.filename: zf.read(info) for info in zf.infolist()}
    except (zipfile.BadZipFile, EOFError, OSError, zlib.error) as exc:
        raise ExportError(f"the zip is truncated or corrupt ({shown(str(exc), 120)})") from None
    for name, raw in data.items():
        if raw.startswith(PICKLE_PROTOCOL_MARK):
            raise ExportError(f"member {name} is a pickle; exports hold no pickles")
    return data


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")


def _json(data: dict[str, bytes], name: str) -> Any:
    """A JSON member, strictly: UTF-8, no NaN or Infinity, nested at most as deep as Python's stack allows."""
    try:
        return json.loads(data[name].decode("utf-8"), parse_constant=_reject_constant)
    except UnicodeDecodeError:
        raise ExportError(f"{name} is not UTF-8 text") from None
    except RecursionError:
        raise ExportError(f"{name} is nested too deeply; not an RBA export") from None
    except ValueError as exc:  # JSONDecodeError, NaN / Infinity, an integer of thousands of digits
        raise ExportError(f"{name} is not JSON ({shown(str(exc), 120)})") from None


def _profile(data: dict[str, bytes]) -> Profile:
    if PROFILE not in data:
        raise ExportError(f"missing member {PROFILE}: not an RBA export")
    profile = Profile.from_json(_json(data, PROFILE))
    if unlisted := sorted(set(data) - set(profile.members) - {PROFILE}):
        raise ExportError(f"member {unlisted[0]} is not listed in {PROFILE}'s members, so nothing checks it")
    for name, sha in profile.members.items():
        if name not in data:
            raise ExportError(f"missing member {name}")
        if hashlib.sha256(data[name]).hexdigest() != sha:
            raise ExportError(f"member {name} does not match its sha256 in {PROFILE}: the zip was changed")
    return profile


def _array(data: dict[str, bytes], name: str, state_dim: int) -> np.ndarray:
    """A condition array: a float32/64 .npy of states (rows of ``state_dim``), header checked before reading."""
    fp = io.BytesIO(data[name])
    headers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        version = np.lib.format.read_magic(fp)
        if version not in headers:
            raise ValueError(f"npy format version {version}; numpy writes 1.0 or 2.0")
        shape, _, dtype = headers[version](fp)
    except (ValueError, OSError, SyntaxError) as exc:
        raise ExportError(f"member {name} is not a plain .npy array ({shown(str(exc), 120)})") from None
    if not (dtype in (np.float32, np.float64) and len(shape) == 2 and 1 <= shape[0] <= MAX_ANCHOR_STATES
            and shape[1] == state_dim):
        raise ExportError(f"member {name} must hold 1 to {MAX_ANCHOR_STATES} states of {state_dim} float32 or "
                          f"float64 values; it holds {shown(shape)} of {shown(str(dtype))}")
    fp.seek(0)
    try:
        array = np.lib.format.read_array(fp, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise ExportError(f"member {name} is not a plain .npy array ({shown(str(exc), 120)})") from None
    if not np.isfinite(array).all():
        raise ExportError(f"member {name} holds NaN or infinite values")
    return array


def _architecture(kind: str, card: Any, domain: Domain) -> list[str]:
    """The card's attribute names, once its architecture's sizes are integers under ``ARCHITECTURE_CAPS``, its
    state size is the domain's and its attribute count the card's: nothing is built before this."""
    arch = card.get("architecture") if isinstance(card, dict) else None
    if not isinstance(arch, dict):
        raise ExportError(f"{REWARD_CARD} must be an object with an architecture")
    for key in REWARD_ARCHITECTURE[kind]:
        value, cap = arch.get(key), ARCHITECTURE_CAPS[key]
        if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= cap):
            raise ExportError(f"{REWARD_CARD} architecture {key} must be an integer in [1, {cap}], got {shown(value)}")
    if arch["state_dim"] != domain.state_dim:
        raise ExportError(f"{REWARD_CARD} architecture state_dim {arch['state_dim']} is not domain "
                          f"{domain.name!r}'s {domain.state_dim}")
    attributes = card.get("attributes")
    if not (isinstance(attributes, list) and len(attributes) == arch["num_attributes"]
            and all(isinstance(a, dict) for a in attributes)):
        raise ExportError(f"{REWARD_CARD} attributes must list architecture num_attributes = "
                          f"{arch['num_attributes']} objects with a name")
    return [_text(a.get("name"), f"{REWARD_CARD} attribute name") for a in attributes]


def _weights(raw: bytes) -> dict[str, torch.Tensor]:
    """``reward.pt``'s tensors by name, read with ``weights_only=True`` once its own records are stored (torch's
    reader would inflate what the outer caps never saw) and its structure small."""
    _check_directory(raw[-END_RECORD_SPAN:], f"member {REWARD_WEIGHTS}", MAX_WEIGHT_RECORDS)
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as zf:
            records = zf.infolist()
    except zipfile.BadZipFile:
        raise ExportError(f"member {REWARD_WEIGHTS} is not a torch state_dict archive") from None
    if len(records) > MAX_WEIGHT_RECORDS or any(
            r.compress_type != zipfile.ZIP_STORED or r.flag_bits & 0x1 or
            (r.filename.endswith("data.pkl") and r.file_size > MAX_PICKLE_BYTES) for r in records):
        raise ExportError(f"member {REWARD_WEIGHTS} is not a torch state_dict archive as torch.save writes one "
                          f"(at most {MAX_WEIGHT_RECORDS} stored records, a structure under {MAX_PICKLE_BYTES >> 20} "
                          "MiB)")
    try:
        weights = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch's reader raises many types on foreign bytes; each is the file's, in one line
        raise ExportError(f"member {REWARD_WEIGHTS} does not load as tensors ({type(exc).__name__}: "
                          f"{shown(str(exc), 120)})") from None
    if not (isinstance(weights, dict) and all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                              for k, v in weights.items())):
        raise ExportError(f"member {REWARD_WEIGHTS} must be a state_dict: tensors by name")
    return weights


def _model(kind: str, card: dict, weights: dict[str, torch.Tensor]) -> torch.nn.Module:
    """rθ built from its (checked) card on the meta device, so nothing is allocated until the weights' names,
    shapes and dtypes are the architecture's and its size under ``MAX_REWARD_PARAMS``; then it takes the tensors."""
    with torch.device("meta"):
        model = BUILDERS[kind](card)
    expected = {k: (tuple(v.shape), v.dtype) for k, v in model.state_dict().items()}
    size = sum(math.prod(shape) for shape, _ in expected.values())
    if size > MAX_REWARD_PARAMS:
        raise ExportError(f"{REWARD_CARD}'s architecture has {size} parameters; a reward has at most "
                          f"{MAX_REWARD_PARAMS}")
    given = {k: (tuple(v.shape), v.dtype) for k, v in weights.items()}
    if given != expected:
        wrong = sorted(set(given) ^ set(expected)) or sorted(k for k in given if given[k] != expected[k])
        raise ExportError(f"member {REWARD_WEIGHTS} does not match {REWARD_CARD}'s architecture: tensor "
                          f"{shown(wrong[0])} is {shown(given.get(wrong[0]))}, expected {expected.get(wrong[0])}")
    if not all(torch.isfinite(v).all() for v in weights.values()):
        raise ExportError(f"member {REWARD_WEIGHTS} holds NaN or infinite values")
    model.load_state_dict(weights, assign=True)
    return model


def _reward(profile: Profile, data: dict[str, bytes]) -> ExportedRewardModel | None:
    spec = profile.reward
    if spec is None:
        return None
    if not isinstance(spec.get("condition"), dict):
        raise ExportError(f"{PROFILE} reward must be null or an object with kind, rep, condition and arrays")
    kind = spec.get("kind")
    if kind not in CONDITIONS or not {REWARD_WEIGHTS, REWARD_CARD} <= set(profile.members):
        raise ExportError(f"reward kind {shown(kind)} unknown or its weights or card missing; valid kinds: "
                          f"{', '.join(CONDITIONS)}")
    card = _json(data, REWARD_CARD)
    names = _architecture(kind, card, profile.check_domain())
    listed = spec.get("arrays", {})
    if not isinstance(listed, dict) or not all(isinstance(m, str) and m in profile.members and m.endswith(".npy")
                                               for m in listed.values()):
        raise ExportError(f"{PROFILE} reward arrays must map names to .npy members listed in its members")
    arrays = {_text(name, f"{PROFILE} reward array name"): _array(data, member, card["architecture"]["state_dim"])
              for name, member in listed.items()}
    CONDITION_CHECKS[kind](spec["condition"], names, arrays)
    model = _model(kind, card, _weights(data[REWARD_WEIGHTS]))
    return ExportedRewardModel(kind, model, card, spec["condition"], arrays)


def _check_global(condition: dict, names: list[str], arrays: dict[str, np.ndarray]) -> None:
    for key in ("v_star", "zeta"):
        v = condition.get(key)
        if not (isinstance(v, list) and len(v) == len(names) and all(_finite(x) for x in v)):
            raise ExportError(f"reward condition {key} must be {len(names)} finite numbers, one per attribute "
                              f"({', '.join(names)})")


def _check_local(condition: dict, names: list[str], arrays: dict[str, np.ndarray]) -> None:
    changes = condition.get("changes")
    if not (isinstance(changes, list) and 0 < len(changes) <= len(names) and all(
            isinstance(c, dict) and c.get("attribute") in names and c.get("direction") in (1, -1)
            and not isinstance(c.get("direction"), bool) for c in changes)):
        raise ExportError(f"reward condition changes must be 1 to {len(names)} {{attribute, direction: 1 or -1}} "
                          f"over {', '.join(names)}")
    if "anchor" not in arrays:
        raise ExportError("a local reward's arrays must hold its anchor")


# reward kind -> the architecture fields its builder reads (each checked against ARCHITECTURE_CAPS first)
REWARD_ARCHITECTURE: dict[str, tuple[str, ...]] = {
    "global_reward": ("state_dim", "num_attributes", "hidden", "layers"),
    "local_reward": ("state_dim", "num_attributes", "embed_dim", "hidden", "layers", "lstm_hidden", "lstm_layers",
                     "anchor_stride"),
}
# reward kind -> a check of its condition (and arrays) against the attributes its card names, as ``rewards`` reads them
CONDITION_CHECKS: dict[str, Callable[[dict, list[str], dict[str, np.ndarray]], None]] = {
    "global_reward": _check_global,
    "local_reward": _check_local,
}


def read_export(path: Path) -> Export:
    """Read and check an export zip (never unpickling); ``ExportError`` with a one-line reason otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ExportError(f"no file {shown(str(path))}")
    _check_directory(_tail(path), shown(path.name), MAX_MEMBERS)
    try:
        with zipfile.ZipFile(path) as zf:
            data = _members(zf, path.stat().st_size)
    except zipfile.BadZipFile as exc:
        raise ExportError(f"{shown(path.name)} is not a zip archive (truncated or not an export: "
                          f"{shown(str(exc), 120)})") from None
    profile = _profile(data)
    if CLIP not in profile.members:
        raise ExportError(f"missing member {CLIP}")
    return Export(profile, data[CLIP], _reward(profile, data))


@dataclass(frozen=True)
class Replay:
    """A profile's behaviour simulated again: measured proxies beside the profile's."""

    profile: Profile
    measured: dict[str, float]

    @property
    def matches(self) -> bool:
        return all(np.isclose(self.measured[a], self.profile.proxies[a], rtol=REPLAY_RTOL, atol=REPLAY_ATOL)
                   for a in self.profile.proxies)


def replay(path: Path) -> Replay:
    """Re-simulate an export's chosen behaviour from its params and seed."""
    profile = read_export(path).profile  # every member checked (the proxies are the domain's attributes)
    rollout = profile.check_domain().rollout(profile.params, profile.seed)
    return Replay(profile, rollout.proxies)
