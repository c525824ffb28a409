"""Checks a CLI's command line against its config before Hydra starts (issue 40).

Hydra resolves ``hydra.run.dir: ${out}`` before a task runs, so a missing required key (``???``)
or a bad config-group choice reached the user as a 100-line traceback, and a missing ``data=``
only after wandb had started. :func:`precheck` composes the config once with Hydra's compose API
(the same config directory and overrides; a sweep's first value stands for the sweep, and every
value of a config-group sweep must name an option of the group) and turns what it finds into one
stated line:

- a required key nobody set: ``required key(s) not set: out (conf/gspi_run.yaml: ???); add out=...``
  (the hint uses the command-line alias of ``eval.common.argv.ALIASES`` where there is one: ``data=...``);
- an unknown config-group choice or key, a malformed override: Hydra's own message, one line.
"""
from __future__ import annotations

from pathlib import Path

from eval.common.argv import ALIASES
from eval.common.errors import StatedError

HYDRA_FLAGS = ("-m", "--multirun", "--cfg", "--info", "-c", "--help", "-h", "--hydra-help", "--resolve",
               "-cn", "--config-name", "-cp", "--config-path", "-cd", "--config-dir", "-p", "--package",
               "--shell-completion", "-sc", "--run", "-r", "--experimental-rerun", "--version")


SCHEMA_PREFIX = "base_"  # STYLE.md 3: schemas are registered as base_<group>


class CommandLineError(StatedError, ValueError):
    """A command line that cannot make a complete config: names the key or the override."""


def first_of_sweeps(overrides: list[str]) -> list[str]:
    """Overrides with every sweep (``k=a,b``, ``k=range(..)``, ``k=choice(..)``) replaced by its first value."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    out = []
    for text, parsed in zip(overrides, OverridesParser.create().parse_overrides(overrides)):
        if parsed.is_sweep_override():
            first = next(iter(parsed.sweep_string_iterator()))
            text = f"{parsed.get_key_element()}={first}"
        out.append(text)
    return out


def sweep_values(overrides: list[str]) -> dict[str, list[str]]:
    """``{group or key: [every value]}`` of each sweep override (``ablation=full,a1,a6``)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return {parsed.key_or_group: list(parsed.sweep_string_iterator())
            for parsed in OverridesParser.create().parse_overrides(overrides) if parsed.is_sweep_override()}


def check_group_choices(sweeps: dict[str, list[str]]) -> None:
    """Every value of a config-group sweep names an option of the group (the first value was
    composed; a typo in a later one would otherwise fail only when Hydra reaches that job)."""
    from hydra.core.global_hydra import GlobalHydra

    loader = GlobalHydra.instance().config_loader()
    for group, values in sweeps.items():
        options = loader.get_group_options(group)
        bad = [v for v in values if options and v not in options and v != "null"]
        if bad:
            raise CommandLineError(f"{group}={bad[0]}: not an option of the config group {group!r} "
                                   f"(available: {', '.join(shown_options(options))})")


def precheck(config_dir: str, config_name: str, argv: list[str]) -> None:
    """Raises :class:`CommandLineError` (one line) when ``argv`` cannot make a complete config."""
    if any(a in HYDRA_FLAGS or a.startswith("--") for a in argv if a not in ("-m", "--multirun")):
        return  # Hydra's own modes (help, --cfg, ...): left to Hydra
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    overrides = [a for a in argv if a not in ("-m", "--multirun")]
    try:
        sweeps = sweep_values(overrides)
        overrides = first_of_sweeps(overrides)
        with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
            try:
                cfg = compose(config_name=config_name, overrides=overrides)
                check_group_choices(sweeps)
                check_appended_keys(overrides)
            except (HydraException, OmegaConfBaseException) as exc:
                hint = did_you_mean(exc, config_name, overrides)
                raise CommandLineError(_hydra_message(exc).rstrip(".") + hint if hint else _hydra_message(exc)) from None
    except (HydraException, OmegaConfBaseException) as exc:
        raise CommandLineError(_hydra_message(exc)) from None
    missing = sorted(k for k in OmegaConf.missing_keys(cfg) if not k.startswith("hydra."))
    if missing:
        source = Path(config_dir) / f"{config_name}.yaml"
        alias_of = {key: alias for alias, key in ALIASES.get(config_name, {}).items()}
        hint = " ".join(f"{alias_of.get(k, k)}=..." for k in missing)
        raise CommandLineError(f"required key(s) not set: {', '.join(missing)} ({source}: ???); add {hint}")


def shown_options(options) -> list[str]:
    """A group's options as a user may choose them: without the structured-config schemas
    (``base_<group>``, registered by ``eval.config.register_configs``, which options extend)."""
    return [o for o in options if not o.startswith(SCHEMA_PREFIX)]


def _hydra_message(exc: BaseException) -> str:
    """Hydra's message without its 'Available options' list (the first line and the choices, joined)."""
    text = str(exc).strip()
    lines = [x.strip() for x in text.splitlines() if x.strip()]
    head = lines[0] if lines else type(exc).__name__
    options = shown_options(x for x in lines[1:] if not x.lower().startswith(
        ("available options", "config search path", "provider=", "in '", "set the environment")))
    if "Available options" in text and options:
        head += f" (available: {', '.join(options[:12])}{', ...' if len(options) > 12 else ''})"
    return head


def check_appended_keys(overrides: list[str]) -> None:
    """``+experimen=table2`` adds a key nobody reads (Hydra accepts it); when its name is close to a
    config group (``experiment``) it is surely that group mistyped: refused, naming the group."""
    import difflib

    from hydra.core.global_hydra import GlobalHydra

    groups = [g for g in GlobalHydra.instance().config_loader().list_groups("") if g != "hydra"]
    for text in overrides:
        if not text.startswith("+") or text.startswith("++") or "=" not in text:
            continue
        key, value = text[1:].split("=", 1)
        if "." in key or "/" in key or key in groups:
            continue
        close = difflib.get_close_matches(key, groups, n=1)
        if close:
            raise CommandLineError(f"{text}: {key!r} is not a config group (it would add a key nothing "
                                   f"reads); did you mean +{close[0]}={value}?")


def did_you_mean(exc: BaseException, config_name: str, overrides: list[str]) -> str:
    """``"; did you mean method?"`` for a mistyped key or config group (``metod=gspi``,
    ``stage2.trian.steps=3``) or group option (``method=gpsi``): the close names
    (``difflib.get_close_matches``) among the keys at that level of the config composed without
    the bad override, and the config groups; "" when nothing is close. Call inside the config dir."""
    import difflib
    import re

    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import DictConfig

    text = str(exc)
    loader = GlobalHydra.instance().config_loader()
    option = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    if option:  # group/option: the group's options
        group, name = option.groups()
        close = difflib.get_close_matches(name, shown_options(loader.get_group_options(group)), n=1)
        return f"; did you mean {group}={close[0]}?" if close else ""
    bad = re.search(r"Could not (?:override|append to|delete from config\.?) '([^']+)'", text)
    if not bad:
        return ""
    key = bad.group(1)
    rest = [o for o in overrides if o.lstrip("+~").split("=", 1)[0] != key]
    try:
        node = compose(config_name=config_name, overrides=rest)
    except Exception:  # another override is bad too: no suggestion
        return ""
    parts, prefix = key.split("."), []
    for k, part in enumerate(parts):
        if isinstance(node, DictConfig) and part in node:
            node, prefix = node[part], prefix + [part]
            continue
        names = list(node.keys()) if isinstance(node, DictConfig) else []
        if k == 0:  # top level: the config groups (method, ablation, ...) and aliases (preset, data)
            names += [g for g in loader.list_groups("") if g != "hydra"] + list(ALIASES.get(config_name, {}))
        close = difflib.get_close_matches(part, [str(n) for n in names], n=1)
        return f"; did you mean {'.'.join(prefix + close + parts[k + 1:])}?" if close else ""
    return ""
