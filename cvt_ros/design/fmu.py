"""``cvt-sim fmu``: the transmission of a scene as an FMI 2.0 Co-Simulation FMU (pythonfmu).

The FMU holds pythonfmu's native library (Linux x86-64 and Windows x86-64), its Python facade,
the model class (:mod:`.fmu_slave`, copied in as ``cvt_transmission.py``) and the scene's values
(``cvt_scene.json``); the model itself is cvt_ros, imported from the importing machine's Python
when the FMU is initialized. docs/design.md says what each importing tool needs.

Parameters: every physics parameter of the scene (:data:`cvt_ros.parameters.PHYSICS_PARAMETERS`)
under its dotted name — numbers as Real (Integer for the assembly mode), choices as String —
fixed once the FMU is initialized. An infinite value (``shaft.stiffness: .inf``, a rigid shaft)
has no FMI literal: it stays fixed as the scene gives it and is left out of the parameters.
"""
import json
import math
import shutil
import tempfile
from pathlib import Path

from .. import parameters
from ..scene import load_scene
from .errors import DesignError

MODULE = 'cvt_transmission'          # the model's module inside the FMU (resources/)


def fmu_parameters(values):
    """name → (kind 'real' | 'integer' | 'string', unit, meaning) of the FMU's parameters; the
    names left out (not finite; the number of paths and their offsets, which set how many
    variables the FMU has: fixed at the scene's, as FMI 2.0 has no structural parameters)."""
    table, fixed = {}, []
    for spec in parameters.PHYSICS_PARAMETERS:
        value = values[spec.name]
        if spec.name.startswith('paths.'):
            fixed.append(spec.name)
            continue
        if isinstance(value, str):
            kind = 'string'
        elif isinstance(value, bool):
            continue
        elif isinstance(value, int):
            kind = 'integer'
        elif math.isfinite(value):
            kind = 'real'
        else:
            fixed.append(spec.name)
            continue
        table[spec.name] = (kind, spec.unit, spec.description)
    return table, fixed


def build_fmu(scene, out, overrides=None, step=1e-3, stop_time=10.0, origins=None):
    """Write the FMU of ``scene`` (name, path or validated values) with ``overrides`` to
    ``out``; (path, a description of its variables). Raises DesignError and the scene's
    errors."""
    from pythonfmu import FmuBuilder

    if isinstance(scene, dict):
        values, name = parameters.validate({**scene, **(overrides or {})}), 'values'
    else:
        values, name = load_scene(scene, overrides, origins), Path(str(scene)).stem
    if not (0.0 < step <= 0.1 and math.isfinite(step)):
        raise DesignError(f"step = {step!r} s: the FMU's communication step must be in (0, 0.1]")
    if not (stop_time > 0.0 and math.isfinite(stop_time)):
        raise DesignError(f"stop_time = {stop_time!r} s must be a positive time")
    table, fixed = fmu_parameters(values)
    config = {'scene': name, 'step': step, 'stop_time': stop_time,
              'values': {k: values[k] for k in table} | {k: values[k] for k in fixed},
              'parameters': table, 'fixed': fixed}
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix='cvt_fmu_') as tmp:
        script = Path(tmp) / f'{MODULE}.py'
        shutil.copyfile(Path(__file__).with_name('fmu_slave.py'), script)
        scene_file = Path(tmp) / 'cvt_scene.json'
        scene_file.write_text(json.dumps(config, indent=1), encoding='utf-8')
        try:
            built = Path(FmuBuilder.build_FMU(script, dest=Path(tmp) / 'fmu',
                                              project_files=[scene_file]))
            _declare_initial_unknowns(built)
            shutil.move(str(built), out)
        except Exception as exc:   # noqa: BLE001 — pythonfmu's own failures, as one line
            raise DesignError(f"cannot build the FMU {out}: {type(exc).__name__}: "
                              f"{exc}") from None
    description = (f"{name}: FMI 2.0 Co-Simulation, step {step:g} s; inputs crank_length_cmd "
                   f"[m], load_torque_cmd [N·m]; outputs <joint>.angle/.speed (crank, rocker, "
                   f"clutch_output, output_shaft), crank_length, clutch_engaged, clutch_torque; "
                   f"{len(table)} parameters"
                   + (f" ({', '.join(fixed)} fixed at the scene's values)" if fixed else ''))
    return out, description


def _declare_initial_unknowns(path):
    """List the outputs under ModelStructure/InitialUnknowns (FMI 2.0 §2.2.8: outputs whose
    initial value is calculated — from the parameters, at initialization — must be there);
    pythonfmu 0.7 writes only ModelStructure/Outputs, which validators reject."""
    import zipfile
    from xml.etree import ElementTree

    with zipfile.ZipFile(path) as zf:
        entries = {info.filename: zf.read(info) for info in zf.infolist()}
    root = ElementTree.fromstring(entries['modelDescription.xml'])
    structure = root.find('ModelStructure')
    outputs = structure.find('Outputs')
    if outputs is not None and structure.find('InitialUnknowns') is None:
        unknowns = ElementTree.SubElement(structure, 'InitialUnknowns')
        for unknown in outputs:
            ElementTree.SubElement(unknowns, 'Unknown', index=unknown.get('index'))
    ElementTree.indent(root)
    entries['modelDescription.xml'] = ElementTree.tostring(root, encoding='UTF-8',
                                                           xml_declaration=True)
    with zipfile.ZipFile(path, 'w', zipfile.ZIP_DEFLATED) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)


__all__ = ['MODULE', 'build_fmu', 'fmu_parameters']
