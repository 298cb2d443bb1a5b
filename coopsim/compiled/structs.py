"""numba StructRef types of the four records the kernels share: PackedModel, Workspace, Loop, Tableau.

A StructRef is passed to compiled functions by reference (one pointer), where a NamedTuple of ~50
arrays is passed by value field by field: with them the package compiles about ten times faster.
Python builds and reads the NamedTuples (`packing`, `integrate`); `to_struct` gives compiled code a
StructRef holding the *same* arrays (no copy), through cached constructors. Field types are fixed:
float64 / int64 C-contiguous arrays and scalars. (This file lists the fields of the NamedTuples in
order; a test checks that the two stay in step.)

Field reads are *borrowed*: compiled code gets a field's array without taking a reference to it (its
meminfo is left null), so reading `W.X` or indexing `W.R[j]` costs no atomic reference-count update.
numba's own StructRef getattr takes one per read, and its refcount pruning cannot remove those that
live across a call or a loop: they were about a third of an evaluation's time. The record keeps its
arrays alive; a field array read in compiled code is valid while the record is, so it must not be
returned to Python or stored in another record (no kernel does either). Fields are still set with a
reference (the constructors below).
"""

from __future__ import annotations

from numba import njit, types
from numba.core import cgutils, imputils
from numba.core.datamodel import default_manager, models
from numba.core.extending import infer_getattr, intrinsic, lower_getattr_generic, lower_setattr_generic
from numba.core.typing.templates import AttributeTemplate
from numba.experimental import structref
from numba.experimental.jitclass.base import imp_dtor
from numba.np.arrayobj import make_array

_F, _I = types.float64, types.int64
_f1, _f2, _f3 = (types.Array(types.float64, d, "C") for d in (1, 2, 3))
_i1 = types.Array(types.int64, 1, "C")


class StructType(types.StructRef):
    """The numba type of a coopsim record (fields as declared below)."""

    def preprocess_fields(self, fields):
        """The declared fields with literal types widened (numba's hook, called when the type is made).

        Args:
            fields: the (name, numba type) pairs of the record, in order.

        Returns:
            tuple: the (name, type) pairs, each type `types.unliteral`.
        """
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


# As `structref.register`, with borrowed field reads (module docstring).
default_manager.register(StructType, models.StructRefModel)


@infer_getattr
class _StructAttribute(AttributeTemplate):
    key = StructType

    def generic_resolve(self, typ, attr):
        return typ.field_dict.get(attr)


def _borrow_array(context, builder, arytype, value):
    """The array `value` with a null meminfo (and parent): numba takes no reference to it."""
    ary = make_array(arytype)(context, builder, value=value)
    ary.meminfo = cgutils.get_null_value(ary.meminfo.type)
    ary.parent = cgutils.get_null_value(ary.parent.type)
    return ary._getvalue()


@lower_getattr_generic(StructType)
def _struct_getattr(context, builder, typ, val, attr):
    value = getattr(structref._Utils(context, builder, typ).get_data_struct(val), attr)
    fieldtype = typ.field_dict[attr]
    if isinstance(fieldtype, types.Array):
        return _borrow_array(context, builder, fieldtype, value)
    return imputils.impl_ret_borrowed(context, builder, fieldtype, value)


@intrinsic
def borrow(typingctx, arr):
    """`arr` borrowed, as a field read (module docstring).

    For a kernel's array arguments, whose owner outlives the call, so that passing them on to other
    kernels costs no reference count. Compiled code calls it as borrow(arr); numba supplies typingctx.

    Args:
        typingctx: numba's typing context.
        arr: the numba type of the argument (an array type; any other type does not match).

    Returns:
        tuple | None: (signature arr(arr), codegen) for an array type; None (no match) otherwise.
    """
    if not isinstance(arr, types.Array):
        return None

    def codegen(context, builder, sig, args):
        return _borrow_array(context, builder, sig.args[0], args[0])

    return arr(arr), codegen


@lower_setattr_generic(StructType)
def _struct_setattr(context, builder, sig, args, attr):
    [inst_type, val_type], [instance, val] = sig.args, args
    data = structref._Utils(context, builder, inst_type).get_data_struct(instance)
    value = context.cast(builder, val, val_type, inst_type.field_dict[attr])
    old = getattr(data, attr)
    context.nrt.incref(builder, val_type, value)
    context.nrt.decref(builder, val_type, old)     # after the incref: the new value may be the old one
    setattr(data, attr, value)


class Struct(structref.StructRefProxy):
    """Python handle of a record; compiled code reads its fields."""


structref.define_boxing(StructType, Struct)

PACKED_FIELDS = (
    ("dof", _i1),
    ("base_pos", _f2),
    ("base_rot", _f3),
    ("joint_pos", _f2),
    ("joint_rot", _f3),
    ("joint_axis", _f2),
    ("joint_k1", _f3),
    ("joint_k2", _f3),
    ("joint_z", _f2),
    ("joint_type", _i1),
    ("link_mass", _f1),
    ("link_com", _f2),
    ("link_inertia", _f3),
    ("ee_pos", _f2),
    ("ee_rot", _f3),
    ("obj_mass", _F),
    ("obj_inertia", _f2),
    ("grasp_pos", _f2),
    ("grasp_rot", _f3),
    ("carrier", _I),
    ("gravity", _f1),
    ("rows", _f2),
    ("rank_tol", _F),
    ("rank_error", _I),
    ("stabilization", _I),
    ("alpha", _F),
    ("beta", _F),
    ("projection_tol", _F),
    ("projection_max_iter", _I),
    ("tq_off", _i1),
    ("tq_t", _f1),
    ("tq_v", _f1),
)
PACKED_T = StructType(list(PACKED_FIELDS))

WORKSPACE_FIELDS = (
    ("p", _f2),
    ("R", _f3),
    ("z", _f2),
    ("c", _f2),
    ("I", _f3),
    ("p_ee", _f2),
    ("R_ee", _f3),
    ("p_rel", _f2),
    ("c_rel", _f2),
    ("p_ee_rel", _f2),
    ("w", _f2),
    ("dw", _f2),
    ("a", _f2),
    ("Mb", _f2),
    ("Lb", _f2),
    ("Lb_inv", _f1),
    ("h", _f1),
    ("h_arm", _f1),
    ("J", _f3),
    ("Jd_qd", _f2),
    ("p_C", _f1),
    ("R_o", _f2),
    ("K_o", _f2),
    ("s", _f2),
    ("J_o", _f2),
    ("Jd_o_qd", _f1),
    ("v_o", _f1),
    ("Y_bias", _f1),
    ("Lam", _f2),
    ("Lam_dot_qd", _f1),
    ("X", _f2),
    ("x0", _f1),
    ("A", _f2),
    ("A_f", _f2),
    ("b", _f1),
    ("F", _f1),
    ("res", _f1),
    ("perm", _i1),
    ("yK", _f1),
    ("phi", _f1),
    ("qdd", _f1),
    ("tau", _f1),
    ("cond", _f1),
    ("rank", _i1),
    ("path", _i1),
    ("dF", _f1),
    ("vec6", _f1),
    ("v3", _f1),
    ("m3", _f3),
    ("d_inv", _f1),
    ("V", _f2),
    ("S", _f2),
    ("S_inv", _f1),
    ("yN", _f1),
)
WORKSPACE_T = StructType(list(WORKSPACE_FIELDS))

LOOP_FIELDS = (
    ("t", _f1),
    ("h", _f1),
    ("y", _f1),
    ("fy", _f1),
    ("has_fy", _i1),
    ("k_next", _i1),
    ("count", _i1),
    ("status", _i1),
    ("fail_t", _f1),
    ("fail_y", _f1),
    ("warn", _i1),
    ("warn_t", _f1),
    ("warn_cond", _f1),
    ("warn_y", _f1),
    ("K", _f2),
    ("y_new", _f1),
    ("ytmp", _f1),
    ("Fd", _f2),
    ("stab", _f1),
    ("step", _f1),
    ("defer", _i1),
    ("raw", _i1),
)
LOOP_T = StructType(list(LOOP_FIELDS))

TABLEAU_FIELDS = (
    ("code", _I),
    ("stages", _I),
    ("A", _f2),
    ("C", _f1),
    ("B", _f1),
    ("E5", _f1),
    ("E3", _f1),
    ("D", _f2),
    ("Pd", _f2),
    ("err_order", _I),
)
TABLEAU_T = StructType(list(TABLEAU_FIELDS))


@intrinsic
def from_record(typingctx, struct_type, record):
    """A new StructRef of `struct_type` holding the fields of the NamedTuple `record`, built in one step.

    Same names in the same order, arrays of the same types; a reference is taken to each. Typing and
    lowering ~50 field assignments one by one took most of the constructors' compile time. Compiled
    code calls it as from_record(STRUCT_T, record); numba supplies typingctx.

    Args:
        typingctx: numba's typing context.
        struct_type: the numba type of the first argument, a type reference to a StructType (PACKED_T,
            WORKSPACE_T, LOOP_T or TABLEAU_T).
        record: the numba type of the NamedTuple.

    Returns:
        tuple | None: (signature, codegen) of the constructor; None (no match) when `record` is not a
        NamedTuple with the struct's field names in order, or one of its arrays has another type.
    """
    inst_type = struct_type.instance_type
    fields = inst_type.field_dict
    if not isinstance(record, types.BaseNamedTuple) or tuple(record.fields) != tuple(fields):
        return None
    if any(isinstance(t, types.Array) and t != fields[f] for f, t in zip(record.fields, record.types)):
        return None

    def codegen(context, builder, sig, args):
        alloc_type = context.data_model_manager[inst_type.get_data_type()].get_value_type()
        size = context.get_constant(types.uintp, context.get_abi_sizeof(alloc_type))
        meminfo = context.nrt.meminfo_alloc_dtor(builder, size, imp_dtor(context, builder.module, inst_type))
        data_pointer = builder.bitcast(context.nrt.meminfo_data(builder, meminfo), alloc_type.as_pointer())
        builder.store(cgutils.get_null_value(alloc_type), data_pointer)
        inst = context.make_helper(builder, inst_type)
        inst.meminfo = meminfo
        data = structref._Utils(context, builder, inst_type).get_data_struct(inst._getvalue())
        for i, (name, fromty) in enumerate(zip(record.fields, record.types)):
            value = context.cast(builder, builder.extract_value(args[1], i), fromty, fields[name])
            context.nrt.incref(builder, fields[name], value)
            setattr(data, name, value)
        return inst._getvalue()

    return inst_type(struct_type, record), codegen


@njit(cache=True)
def _new_packed(r):
    return from_record(PACKED_T, r)


@njit(cache=True)
def _new_workspace(r):
    return from_record(WORKSPACE_T, r)


@njit(cache=True)
def _new_loop(r):
    return from_record(LOOP_T, r)


@njit(cache=True)
def _new_tableau(r):
    return from_record(TABLEAU_T, r)


_NEW = {"PackedModel": _new_packed, "Workspace": _new_workspace, "Loop": _new_loop, "Tableau": _new_tableau}


def to_struct(record) -> Struct:
    """The StructRef of a PackedModel, Workspace, Loop or Tableau NamedTuple (sharing its arrays).

    Args:
        record: the NamedTuple (`coopsim.compiled.packing` / `coopsim.compiled.integrate`), its arrays
            float64 / int64 C-contiguous.

    Returns:
        Struct: the Python handle of the StructRef holding the same arrays (no copy).
    """
    return _NEW[type(record).__name__](record)
