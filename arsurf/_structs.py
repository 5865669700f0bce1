"""A numba struct whose fields a kernel compiled without reference counts can read.

:func:`register` is ``numba.experimental.structref.register`` (the struct's data model, the
typing of its fields, reading and writing them) with one difference: a function compiled with
``_nrt=False`` reads a field *borrowed*, without taking a reference to it. Numba's own reading
takes one (an atomic increment, and a decrement when the field's variable dies) and needs the
reference-counting runtime to find the struct's payload: 24 fields read cost ~250 ns a call in a
micro-benchmark, and the haptic loop's tick, which reads ~45, is 0.4-0.7 us faster without
(docs/performance.rst, "The model tick without reference counts"). Borrowing is safe for the
same reason as the rest of such a kernel: the caller holds the struct, and the struct its fields,
for the whole call; the kernel never writes a field (only into the arrays the fields are).

The payload is found as numba finds it (``NRT_MemInfo_data_fast``): the ``data`` member of the
MemInfo, in numba's own declaration of its layout (``numba.core.runtime.nrtdynmod``).
"""
from __future__ import annotations

from numba.core import cgutils, imputils
from numba.core.datamodel import default_manager, models
from numba.core.extending import infer_getattr, lower_getattr_generic, lower_setattr_generic
from numba.core.runtime.nrtdynmod import _meminfo_struct_type
from numba.core.typing.templates import AttributeTemplate
from numba.experimental import structref

#: the index of ``void *data`` in numba's MemInfo struct
_DATA = 3


def register(struct_typeclass):
    """Register ``struct_typeclass`` (a ``numba.types.StructRef`` subclass) for jit code, as
    ``structref.register`` does, its fields read borrowed where reference counts are off."""
    default_manager.register(struct_typeclass, models.StructRefModel)

    @infer_getattr
    class _Attribute(AttributeTemplate):
        key = struct_typeclass

        def generic_resolve(self, typ, attr):
            return typ.field_dict.get(attr)

    @lower_getattr_generic(struct_typeclass)
    def _get(context, builder, typ, val, attr):
        if context.enable_nrt:  # numba's: the field with a reference taken
            ret = getattr(structref._Utils(context, builder, typ).get_data_struct(val), attr)
            return imputils.impl_ret_borrowed(context, builder, typ.field_dict[attr], ret)
        meminfo = cgutils.create_struct_proxy(typ)(context, builder, value=val).meminfo
        info = builder.bitcast(meminfo, _meminfo_struct_type.as_pointer())
        payload = typ.get_data_type()
        data = builder.bitcast(builder.load(cgutils.gep(builder, info, 0, _DATA)),
                               context.data_model_manager[payload].get_value_type().as_pointer())
        return getattr(cgutils.create_struct_proxy(payload)(context, builder, ref=data), attr)

    @lower_setattr_generic(struct_typeclass)
    def _set(context, builder, sig, args, attr):  # numba's (the constructor's; needs the runtime)
        inst_type, val_type = sig.args
        instance, val = args
        data = structref._Utils(context, builder, inst_type).get_data_struct(instance)
        casted = context.cast(builder, val, val_type, inst_type.field_dict[attr])
        old = getattr(data, attr)
        context.nrt.incref(builder, val_type, casted)
        context.nrt.decref(builder, val_type, old)
        setattr(data, attr, casted)

    return struct_typeclass
