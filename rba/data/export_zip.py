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
import zipfile
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from rba.core.artifacts import BUILDERS, ModelNotFoundError, load_model, weights_sha
from rba.core.fileio import write_atomic
from rba.core.methods import get_method
from rba.data.library import SkillLibrary
from rba.domains import Domain, Rollout, domain_names, get_domain
from rba.learn.common import Ragged
from rba.learn.global_reward import RefitConfig, refit_for_target

FORMAT = "rba-export"
FORMAT_VERSION = 1
PROFILE, CLIP, REWARD_WEIGHTS, REWARD_CARD = "profile.json", "clip.mp4", "reward.pt", "reward.json"
SIMULATORS = ("mujoco", "dm-control", "highway-env", "gymnasium")  # package versions a replay depends on
PICKLE_PROTOCOL_MARK = b"\x80"  # every pickle of protocol 2+ starts with the PROTO opcode
DOMAIN_REFIT = "domain"  # ExportSource.refit: as the domain chooses
REPLAY_RTOL, REPLAY_ATOL = 1e-6, 1e-9  # a replayed proxy "matches" within these (same packages: bit-exact)
MAX_MEMBER_BYTES = 64 << 20  # a member's size, unpacked: a clip is a few MB, a reward's weights under one
MAX_EXPORT_BYTES = 256 << 20  # all members, unpacked: read into memory, so a small zip may not unpack to GBs
SEED_BITS = 32  # a profile's seed is below 2**SEED_BITS: every domain's generator takes it (library seeds < 4e6)


class ExportError(ValueError):
    """An export that cannot be made or read; the message is one line naming what is wrong."""


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


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
        for name, values in (("proxies", profile.proxies), ("zeta", profile.zeta or {})):
            if not isinstance(values, dict) or not all(_is_number(v) for v in values.values()):
                raise ExportError(f"{PROFILE} {name} must map attribute names to numbers")
        profile.check_domain()
        return profile

    def check_domain(self) -> Domain:
        """The profile's domain, if registered and its params are exactly the domain's ``param_names``."""
        if self.domain not in domain_names():
            raise ExportError(f"unknown domain {self.domain!r}; valid: {', '.join(domain_names())}")
        domain = get_domain(self.domain)
        if not isinstance(self.params, dict) or sorted(self.params) != sorted(domain.param_names):
            given = sorted(self.params) if isinstance(self.params, dict) else self.params
            raise ExportError(f"params {given} do not match domain {self.domain!r}'s param_names "
                              f"{list(domain.param_names)}")
        if not all(_is_number(v) for v in self.params.values()):
            raise ExportError("params must be numbers")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or not 0 <= self.seed < 2**SEED_BITS:
            raise ExportError(f"seed must be an integer in [0, 2**{SEED_BITS}), got {self.seed!r}")
        space = domain.param_space()
        if outside := space.outside(self.params):
            name = outside[0]
            raise ExportError(f"param {name} = {self.params[name]!r} is outside domain {self.domain!r}'s range "
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


def export_bytes(profile: Profile, reward: RewardPart | None, clip: bytes) -> bytes:
    """The zip's bytes: every member, then ``profile.json`` naming each one's sha256."""
    members = {CLIP: clip}
    if reward is not None:
        weights = io.BytesIO()
        torch.save({k: v.detach().cpu() for k, v in reward.weights.items()}, weights)
        members[REWARD_WEIGHTS] = weights.getvalue()
        members[REWARD_CARD] = json.dumps(reward.card, indent=2, sort_keys=True).encode()
        members.update({f"{name}.npy": _npy(a) for name, a in reward.arrays.items()})
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


def _check_listing(infos: list[zipfile.ZipInfo]) -> None:
    """Each member once, and sizes an export has, before anything is unpacked."""
    if twice := sorted(n for n, k in Counter(info.filename for info in infos).items() if k > 1):
        raise ExportError(f"member {twice[0]} appears more than once; an export holds each member once")
    if big := [i.filename for i in infos if i.file_size > MAX_MEMBER_BYTES]:
        raise ExportError(f"member {big[0]} unpacks to more than {MAX_MEMBER_BYTES >> 20} MiB; not an RBA export")
    if sum(i.file_size for i in infos) > MAX_EXPORT_BYTES:
        raise ExportError(f"the members unpack to more than {MAX_EXPORT_BYTES >> 20} MiB; not an RBA export")


def _members(zf: zipfile.ZipFile) -> dict[str, bytes]:
    _check_listing(zf.infolist())
    try:
        data = {info.filename: zf.read(info) for info in zf.infolist()}
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ExportError(f"the zip is truncated or corrupt ({exc})") from None
    for name, raw in data.items():
        if raw.startswith(PICKLE_PROTOCOL_MARK):
            raise ExportError(f"member {name} is a pickle; exports hold no pickles")
    return data


def _profile(data: dict[str, bytes]) -> Profile:
    if PROFILE not in data:
        raise ExportError(f"missing member {PROFILE}: not an RBA export")
    try:
        obj = json.loads(data[PROFILE])
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ExportError(f"{PROFILE} is not JSON ({exc})") from None
    profile = Profile.from_json(obj)
    if not isinstance(profile.members, dict):
        raise ExportError(f"{PROFILE} members must map names to sha256")
    if unlisted := sorted(set(data) - set(profile.members) - {PROFILE}):
        raise ExportError(f"member {unlisted[0]} is not listed in {PROFILE}'s members, so nothing checks it")
    for name, sha in profile.members.items():
        if name not in data:
            raise ExportError(f"missing member {name}")
        if hashlib.sha256(data[name]).hexdigest() != sha:
            raise ExportError(f"member {name} does not match its sha256 in {PROFILE}: the zip was changed")
    return profile


def _array(data: dict[str, bytes], name: str) -> np.ndarray:
    try:
        return np.lib.format.read_array(io.BytesIO(data[name]), allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise ExportError(f"member {name} is not a plain .npy array ({exc})") from None


def _reward(profile: Profile, data: dict[str, bytes]) -> ExportedRewardModel | None:
    spec = profile.reward
    if spec is None:
        return None
    if not isinstance(spec, dict) or not isinstance(spec.get("condition"), dict):
        raise ExportError(f"{PROFILE} reward must be null or an object with kind, rep, condition and arrays")
    if spec.get("kind") not in CONDITIONS or REWARD_WEIGHTS not in profile.members:
        raise ExportError(f"reward kind {spec.get('kind')!r} unknown or its weights missing; valid kinds: "
                          f"{', '.join(CONDITIONS)}")
    if not zipfile.is_zipfile(io.BytesIO(data[REWARD_WEIGHTS])):
        raise ExportError(f"member {REWARD_WEIGHTS} is not a torch state_dict archive")
    try:
        card = json.loads(data[REWARD_CARD])
        weights = torch.load(io.BytesIO(data[REWARD_WEIGHTS]), map_location="cpu", weights_only=True)
        model = BUILDERS[spec["kind"]](card)
        model.load_state_dict(weights)
        names = [a["name"] for a in card["attributes"]]
    except Exception as exc:  # any failure to rebuild the model is the file's, named in one line
        raise ExportError(f"member {REWARD_WEIGHTS} does not load as a {spec['kind']} "
                          f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    listed = spec.get("arrays", {})
    if not isinstance(listed, dict) or not all(isinstance(m, str) and m in profile.members for m in listed.values()):
        raise ExportError(f"{PROFILE} reward arrays must map names to members listed in its members")
    arrays = {name: _array(data, member) for name, member in listed.items()}
    CONDITION_CHECKS[spec["kind"]](spec["condition"], names, arrays)
    return ExportedRewardModel(spec["kind"], model, card, spec["condition"], arrays)


def _check_global(condition: dict, names: list[str], arrays: dict[str, np.ndarray]) -> None:
    v = condition.get("v_star")
    if not (isinstance(v, list) and len(v) == len(names) and all(_is_number(x) for x in v)):
        raise ExportError(f"reward condition v_star must be {len(names)} numbers, one per attribute "
                          f"({', '.join(map(str, names))})")


def _check_local(condition: dict, names: list[str], arrays: dict[str, np.ndarray]) -> None:
    changes = condition.get("changes")
    if not (isinstance(changes, list) and changes and all(
            isinstance(c, dict) and c.get("attribute") in names and c.get("direction") in (1, -1) for c in changes)):
        raise ExportError(f"reward condition changes must be a list of {{attribute, direction: 1 or -1}} over "
                          f"{', '.join(map(str, names))}")
    if "anchor" not in arrays:
        raise ExportError("a local reward's arrays must hold its anchor")


# reward kind -> a check of its condition (and arrays) against the attributes its card names, as ``rewards`` reads them
CONDITION_CHECKS: dict[str, Callable[[dict, list[str], dict[str, np.ndarray]], None]] = {
    "global_reward": _check_global,
    "local_reward": _check_local,
}


def read_export(path: Path) -> Export:
    """Read and check an export zip (never unpickling); ``ExportError`` with a one-line reason otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ExportError(f"no file {path}")
    if not zipfile.is_zipfile(path):
        raise ExportError(f"{path.name} is not a zip archive (truncated or not an export)")
    try:
        with zipfile.ZipFile(path) as zf:
            data = _members(zf)
    except zipfile.BadZipFile as exc:
        raise ExportError(f"{path.name} is not a readable zip ({exc})") from None
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
    profile = read_export(path).profile
    domain = profile.check_domain()
    if sorted(profile.proxies) != sorted(domain.attribute_names):
        raise ExportError(f"the profile's attributes {sorted(profile.proxies)} are not domain {profile.domain!r}'s "
                          f"{list(domain.attribute_names)}")
    rollout = domain.rollout(profile.params, profile.seed)
    return Replay(profile, rollout.proxies)
