/* The per-chunk entry of the NovAtel framer, in C: drivers.novatel._feed.FeedGate.

   A serial port at 460 800 baud delivers 1-64 bytes per read. Most reads change no verdict of the
   framer: the bytes are the rest of a binary log whose length is known, or text bytes that are not
   the '*', line break or CRC digit a frame waits for. For those, feed() only appends the chunk to
   the held bytes and compares a length, and at most looks the byte up in a set. Written in Python
   that is a Python call plus a few attribute loads per read, which is most of what a 1-byte-at-a-time
   feed costs; here it is one C call.

   Everything else stays in Python (drivers/novatel/framer.py): FeedGate is the base class of
   Framer, holds the wait state that Framer's parsers set (the same attribute names, as slots), and
   calls Framer._look() when a fed chunk may change a verdict. The decision is the one of
   framer._PyFeedGate.feed, the pure-Python twin used when this extension is not built; the tests
   run the framer's whole suite through both and require the same frames and counts.

   Attributes (set by Framer; read here on each feed):
     _acc          bytearray: the bytes held
     _quiet_len    int: below this length no byte can end the wait (a frame's known rest)
     _wake_len     int: below this length only a byte of _wake_set can end the wait
     _wake_set     frozenset of 1-byte bytes, or None: no byte ends the wait
     _wake_search  callable(chunk) -> match or None: finds a byte of _wake_set in a longer chunk
     _quiet        frozenset of the 1-byte bytes objects that are not in _wake_set
*/
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>

typedef struct {
    PyObject_HEAD
    PyObject *acc;
    PyObject *quiet_len;
    PyObject *wake_len;
    PyObject *wake_set;
    PyObject *wake_search;
    PyObject *quiet;
} FeedGate;

static PyObject *no_frames;   /* the shared empty tuple */
static PyObject *look_name;   /* "_look" */

static int
gate_traverse(FeedGate *self, visitproc visit, void *arg)
{
    Py_VISIT(Py_TYPE(self));
    Py_VISIT(self->acc);
    Py_VISIT(self->quiet_len);
    Py_VISIT(self->wake_len);
    Py_VISIT(self->wake_set);
    Py_VISIT(self->wake_search);
    Py_VISIT(self->quiet);
    return 0;
}

static int
gate_clear(FeedGate *self)
{
    Py_CLEAR(self->acc);
    Py_CLEAR(self->quiet_len);
    Py_CLEAR(self->wake_len);
    Py_CLEAR(self->wake_set);
    Py_CLEAR(self->wake_search);
    Py_CLEAR(self->quiet);
    return 0;
}

static void
gate_dealloc(FeedGate *self)
{
    PyTypeObject *tp = Py_TYPE(self);
    PyObject_GC_UnTrack(self);
    gate_clear(self);
    tp->tp_free((PyObject *)self);
    Py_DECREF(tp);
}

static int
unset(PyObject *value, const char *name)
{
    if (value == NULL) {
        PyErr_Format(PyExc_AttributeError, "FeedGate.%s is not set (Framer.__init__ sets it)", name);
        return 1;
    }
    return 0;
}

/* The held bytes' length compared with an int attribute: -1 below, 0 at or above, -2 on error. */
static int
below(Py_ssize_t n, PyObject *limit, const char *name)
{
    if (unset(limit, name)) {
        return -2;
    }
    Py_ssize_t value = PyLong_AsSsize_t(limit);
    if (value == -1 && PyErr_Occurred()) {
        return -2;
    }
    return n < value ? -1 : 0;
}

PyDoc_STRVAR(feed_doc,
"feed(data)\n--\n\n"
"Add bytes; return the frames completed by them (in stream order; ``()`` for none).");

static PyObject *
gate_feed(FeedGate *self, PyObject *data)
{
    PyObject *acc = self->acc;
    if (unset(acc, "_acc")) {
        return NULL;
    }
    if (!PyByteArray_Check(acc)) {
        PyErr_Format(PyExc_TypeError, "FeedGate._acc must be a bytearray, not %.100s", Py_TYPE(acc)->tp_name);
        return NULL;
    }
    /* acc += data */
    Py_ssize_t old = PyByteArray_GET_SIZE(acc);
    Py_ssize_t len;
    if (PyBytes_CheckExact(data)) {
        len = PyBytes_GET_SIZE(data);
        if (len > 0) {
            if (PyByteArray_Resize(acc, old + len) < 0) {
                return NULL;
            }
            memcpy(PyByteArray_AS_STRING(acc) + old, PyBytes_AS_STRING(data), (size_t)len);
        }
    }
    else {
        Py_buffer view;
        if (PyObject_GetBuffer(data, &view, PyBUF_SIMPLE) != 0) {
            PyErr_Clear();
            PyErr_Format(PyExc_TypeError, "can't concat %.100s to bytearray", Py_TYPE(data)->tp_name);
            return NULL;
        }
        len = view.len;
        if (len > 0 && PyByteArray_Resize(acc, old + len) < 0) {
            PyBuffer_Release(&view);
            return NULL;
        }
        if (len > 0) {
            memcpy(PyByteArray_AS_STRING(acc) + old, view.buf, (size_t)len);
        }
        PyBuffer_Release(&view);
    }
    Py_ssize_t n = old + len;

    int verdict = below(n, self->quiet_len, "_quiet_len");
    if (verdict == -2) {
        return NULL;
    }
    if (verdict == -1) {  /* a frame's known rest: no byte can end the wait before its end */
        return Py_NewRef(no_frames);
    }
    verdict = below(n, self->wake_len, "_wake_len");
    if (verdict == -2) {
        return NULL;
    }
    if (verdict == -1) {
        /* No frame can complete, or be rejected, before the wake condition: keep the bytes only. */
        if (unset(self->wake_set, "_wake_set")) {
            return NULL;
        }
        if (self->wake_set == Py_None) {
            return Py_NewRef(no_frames);
        }
        if (len == 1 && PyBytes_CheckExact(data)) {
            /* a serial port's typical read, one byte: one set lookup. A byte not in _quiet is in
               _wake_set, which _wake_search would find: look. */
            if (unset(self->quiet, "_quiet")) {
                return NULL;
            }
            int quiet = PySet_Contains(self->quiet, data);
            if (quiet < 0) {
                return NULL;
            }
            if (quiet) {
                return Py_NewRef(no_frames);
            }
        }
        else {
            if (unset(self->wake_search, "_wake_search")) {
                return NULL;
            }
            PyObject *found = PyObject_CallOneArg(self->wake_search, data);
            if (found == NULL) {
                return NULL;
            }
            int none = found == Py_None;
            Py_DECREF(found);
            if (none) {
                return Py_NewRef(no_frames);
            }
        }
    }
    return PyObject_CallMethodNoArgs((PyObject *)self, look_name);
}

static PyMethodDef gate_methods[] = {
    {"feed", (PyCFunction)gate_feed, METH_O, feed_doc},
    {NULL, NULL, 0, NULL},
};

static PyMemberDef gate_members[] = {
    {"_acc", T_OBJECT_EX, offsetof(FeedGate, acc), 0, "the bytes held (a bytearray)"},
    {"_quiet_len", T_OBJECT_EX, offsetof(FeedGate, quiet_len), 0, "below it, no byte ends the wait"},
    {"_wake_len", T_OBJECT_EX, offsetof(FeedGate, wake_len), 0, "below it, only a byte of _wake_set does"},
    {"_wake_set", T_OBJECT_EX, offsetof(FeedGate, wake_set), 0, "the bytes that end the wait, or None"},
    {"_wake_search", T_OBJECT_EX, offsetof(FeedGate, wake_search), 0, "finds a byte of _wake_set in a chunk"},
    {"_quiet", T_OBJECT_EX, offsetof(FeedGate, quiet), 0, "the 1-byte chunks not in _wake_set"},
    {NULL, 0, 0, 0, NULL},
};

static PyType_Slot gate_slots[] = {
    {Py_tp_doc, "The per-chunk entry of drivers.novatel.Framer, in C (see the module's source)."},
    {Py_tp_dealloc, gate_dealloc},
    {Py_tp_traverse, gate_traverse},
    {Py_tp_clear, gate_clear},
    {Py_tp_methods, gate_methods},
    {Py_tp_members, gate_members},
    {0, NULL},
};

static PyType_Spec gate_spec = {
    .name = "drivers.novatel._feed.FeedGate",
    .basicsize = sizeof(FeedGate),
    .itemsize = 0,
    .flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE | Py_TPFLAGS_HAVE_GC,
    .slots = gate_slots,
};

static int
feed_exec(PyObject *module)
{
    no_frames = PyTuple_New(0);
    if (no_frames == NULL) {
        return -1;
    }
    look_name = PyUnicode_InternFromString("_look");
    if (look_name == NULL) {
        return -1;
    }
    PyObject *type = PyType_FromModuleAndSpec(module, &gate_spec, NULL);
    if (type == NULL) {
        return -1;
    }
    int rc = PyModule_AddObjectRef(module, "FeedGate", type);
    Py_DECREF(type);
    return rc;
}

static PyModuleDef_Slot feed_module_slots[] = {
    {Py_mod_exec, feed_exec},
    {0, NULL},
};

static struct PyModuleDef feed_module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "drivers.novatel._feed",
    .m_doc = "The per-chunk entry of the NovAtel framer, in C (drivers.novatel.framer has its pure-Python twin).",
    .m_size = 0,
    .m_methods = NULL,
    .m_slots = feed_module_slots,
};

PyMODINIT_FUNC
PyInit__feed(void)
{
    return PyModuleDef_Init(&feed_module);
}
