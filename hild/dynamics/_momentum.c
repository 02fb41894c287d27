/* The momentum observer's per-cycle update, compiled (hild/dynamics/momentum.py, docs/performance.md "The
 * observer's cost").
 *
 * Why: on the cycle the update is a handful of MuJoCo calls and a recursion over six numbers; through Python each
 * MuJoCo call pays the bindings' argument conversion and the recursion pays the interpreter, together about twice
 * what MuJoCo itself computes. Here the same steps run in one call, in the same order and with the same arithmetic
 * (no contraction into fused multiply-adds: -ffp-contract=off), so the result is the Python path's to the bit —
 * momentum.py checks that on every observer it builds before it uses this, and falls back to Python otherwise.
 *
 * No MuJoCo header is used: the caller hands over the addresses of mjModel and mjData, of the MuJoCo functions
 * (taken from the library the mujoco package loaded), and of every array this reads or writes (views into mjData
 * or arrays the observer owns, kept alive by this object). Only MuJoCo's public C signatures are relied on.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

typedef void (*stage_fn)(const void *m, void *d);
typedef void (*rne_fn)(const void *m, void *d, int flg_acc, double *result);
typedef void (*mulm_fn)(const void *m, void *d, double *res, const double *vec);

enum { K_KINEMATICS, K_COMPOS, K_MAKEM, K_FWDPOSITION, K_FWDVELOCITY, K_RNE, K_MULM, N_FUNCTIONS };

typedef struct {
    PyObject_HEAD
    PyObject *keep; /* the arrays and MuJoCo objects whose memory is used below */
    const void *m;
    void *d;
    stage_fn kinematics, compos, makem, fwdposition, fwdvelocity;
    rne_fn rne;
    mulm_fn mulm;
    Py_ssize_t n, nv;
    int staged, with_gravity;
    Py_ssize_t ncvel, ncdof_dot;
    /* views into mjData */
    double *qpos, *qvel, *bias, *passive, *cvel, *cdof_dot;
    /* the observer's own arrays: step, mass_prev, mass_now, gravity_full (nv); residual, gravity (n) */
    double *step, *mass_prev, *mass_now, *gravity_full, *residual, *gravity;
    /* the recursion's state (n each) and the joints' addresses */
    double *r, *bias_prev, *passive_prev;
    Py_ssize_t *qposadr, *dofadr;
    double gain;
} Kernel;

static void Kernel_dealloc(Kernel *self) {
    PyMem_Free(self->r);
    PyMem_Free(self->qposadr);
    Py_XDECREF(self->keep);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* A writable, C-contiguous float64 array of exactly ``size`` entries: its data pointer (NULL and an error set). */
static double *float_buffer(PyObject *obj, Py_ssize_t size, const char *what) {
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return NULL;
    int ok = view.itemsize == 8 && view.format != NULL && strcmp(view.format, "d") == 0 && view.len == size * 8;
    double *data = (double *)view.buf;
    PyBuffer_Release(&view); /* the memory stays alive through ``keep`` */
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd contiguous float64 values", what, size);
        return NULL;
    }
    return data;
}

/* Read-only float64 input of ``n`` entries (q, q̇, τ each cycle), copied into ``out``. */
static int read_input(PyObject *obj, Py_ssize_t n, double *out, const char *what) {
    Py_buffer view;
    if (PyObject_GetBuffer(obj, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) return -1;
    int ok = view.itemsize == 8 && view.format != NULL && strcmp(view.format, "d") == 0 && view.len == n * 8;
    if (ok) memcpy(out, view.buf, (size_t)n * sizeof(double));
    PyBuffer_Release(&view);
    if (!ok) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd contiguous float64 values", what, n);
        return -1;
    }
    return 0;
}

static void *address(PyObject *seq, Py_ssize_t i) {
    PyObject *item = PySequence_GetItem(seq, i);
    if (item == NULL) return NULL;
    void *p = PyLong_AsVoidPtr(item);
    Py_DECREF(item);
    return p;
}

/* Kernel(model_address, data_address, functions, arrays, qposadr, dofadr, gain, staged, with_gravity, keep)
 * functions: the addresses of mj_kinematics, mj_comPos, mj_makeM, mj_fwdPosition, mj_fwdVelocity, mj_rne, mj_mulM.
 * arrays: (qpos, qvel, qfrc_bias, qfrc_passive, cvel, cdof_dot, step, mass_prev, mass_now, gravity_full, residual,
 * gravity) — numpy arrays (views into mjData for the first six). */
static int Kernel_init(Kernel *self, PyObject *args, PyObject *kwds) {
    PyObject *model_address, *data_address, *functions, *arrays, *qposadr, *dofadr, *keep;
    double gain;
    int staged, with_gravity;
    if (!PyArg_ParseTuple(args, "OOOOOOdppO", &model_address, &data_address, &functions, &arrays, &qposadr, &dofadr,
                          &gain, &staged, &with_gravity, &keep))
        return -1;
    if (self->keep != NULL) {
        PyErr_SetString(PyExc_RuntimeError, "a kernel is initialized once");
        return -1;
    }
    Py_INCREF(keep);
    self->keep = keep;
    self->m = PyLong_AsVoidPtr(model_address);
    self->d = PyLong_AsVoidPtr(data_address);
    if (PyErr_Occurred()) return -1;
    if (PySequence_Size(functions) != N_FUNCTIONS) {
        PyErr_SetString(PyExc_ValueError, "expected 7 MuJoCo function addresses");
        return -1;
    }
    void *fn[N_FUNCTIONS];
    for (Py_ssize_t i = 0; i < N_FUNCTIONS; i++) {
        fn[i] = address(functions, i);
        if (fn[i] == NULL) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "a MuJoCo function address is NULL");
            return -1;
        }
    }
    self->kinematics = (stage_fn)fn[K_KINEMATICS];
    self->compos = (stage_fn)fn[K_COMPOS];
    self->makem = (stage_fn)fn[K_MAKEM];
    self->fwdposition = (stage_fn)fn[K_FWDPOSITION];
    self->fwdvelocity = (stage_fn)fn[K_FWDVELOCITY];
    self->rne = (rne_fn)fn[K_RNE];
    self->mulm = (mulm_fn)fn[K_MULM];
    self->gain = gain;
    self->staged = staged;
    self->with_gravity = with_gravity;

    Py_ssize_t n = PySequence_Size(qposadr);
    if (n < 0 || PySequence_Size(dofadr) != n || PySequence_Size(arrays) != 12) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "expected 12 arrays and n addresses of each kind");
        return -1;
    }
    self->n = n;
    PyObject *a[12];
    for (Py_ssize_t i = 0; i < 12; i++) {
        a[i] = PySequence_GetItem(arrays, i); /* borrowed for this call only: ``keep`` holds them */
        if (a[i] == NULL) return -1;
        Py_DECREF(a[i]);
    }
    Py_ssize_t sizes[12];
    for (Py_ssize_t i = 0; i < 12; i++) {
        Py_ssize_t s = PyObject_Length(a[i]);
        if (s < 0) return -1;
        sizes[i] = s;
    }
    /* numpy's len() of a 2-D array is its rows: cvel and cdof_dot are flattened by the caller */
    Py_ssize_t nq = sizes[0], nv = sizes[1];
    self->nv = nv;
    self->ncvel = sizes[4];
    self->ncdof_dot = sizes[5];
    const char *names[12] = {"qpos", "qvel", "qfrc_bias", "qfrc_passive", "cvel", "cdof_dot",
                             "step", "mass_prev", "mass_now", "gravity_full", "residual", "gravity"};
    Py_ssize_t expect[12] = {nq, nv, nv, nv, sizes[4], sizes[5], nv, nv, nv, nv, n, n};
    double **slot[12] = {&self->qpos, &self->qvel, &self->bias, &self->passive, &self->cvel, &self->cdof_dot,
                         &self->step, &self->mass_prev, &self->mass_now, &self->gravity_full, &self->residual,
                         &self->gravity};
    for (Py_ssize_t i = 0; i < 12; i++) {
        *slot[i] = float_buffer(a[i], expect[i], names[i]);
        if (*slot[i] == NULL) return -1;
    }
    self->r = PyMem_Calloc((size_t)(3 * n + 1), sizeof(double));
    self->qposadr = PyMem_Calloc((size_t)(2 * n + 1), sizeof(Py_ssize_t));
    if (self->r == NULL || self->qposadr == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    self->bias_prev = self->r + n;
    self->passive_prev = self->r + 2 * n;
    self->dofadr = self->qposadr + n;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *qa = PySequence_GetItem(qposadr, i), *da = PySequence_GetItem(dofadr, i);
        self->qposadr[i] = qa ? PyLong_AsSsize_t(qa) : -1;
        self->dofadr[i] = da ? PyLong_AsSsize_t(da) : -1;
        Py_XDECREF(qa);
        Py_XDECREF(da);
        if (PyErr_Occurred()) return -1;
        if (self->qposadr[i] < 0 || self->qposadr[i] >= nq || self->dofadr[i] < 0 || self->dofadr[i] >= nv) {
            PyErr_Format(PyExc_ValueError, "joint %zd: address outside the model", i);
            return -1;
        }
    }
    return 0;
}

/* momentum.py's ``_evaluate``: the reading into mjData, the position stages, g(q) if asked, then the velocity ones */
static void evaluate(Kernel *k, const double *q, const double *qd) {
    for (Py_ssize_t i = 0; i < k->n; i++) {
        k->qpos[k->qposadr[i]] = q[i];
        k->qvel[k->dofadr[i]] = qd[i];
    }
    if (k->staged) {
        k->kinematics(k->m, k->d);
        k->compos(k->m, k->d);
        k->makem(k->m, k->d);
    } else {
        k->fwdposition(k->m, k->d);
    }
    if (k->with_gravity) {
        memset(k->cvel, 0, (size_t)k->ncvel * sizeof(double));
        memset(k->cdof_dot, 0, (size_t)k->ncdof_dot * sizeof(double));
        k->rne(k->m, k->d, 0, k->gravity_full);
        for (Py_ssize_t i = 0; i < k->n; i++) k->gravity[i] = k->gravity_full[k->dofadr[i]];
    }
    k->fwdvelocity(k->m, k->d);
}

/* reset(q, qd): start again at this reading (p̂ = p, r = 0) */
static PyObject *Kernel_reset(Kernel *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "reset(q, qd)");
        return NULL;
    }
    Py_ssize_t n = self->n;
    double q[n + 1], qd[n + 1];
    if (read_input(args[0], n, q, "q") < 0 || read_input(args[1], n, qd, "qd") < 0) return NULL;
    evaluate(self, q, qd);
    for (Py_ssize_t i = 0; i < n; i++) {
        self->bias_prev[i] = self->bias[self->dofadr[i]];
        self->passive_prev[i] = self->passive[self->dofadr[i]];
        self->r[i] = 0.0;
        self->residual[i] = 0.0;
    }
    Py_RETURN_NONE;
}

/* update(q, qd, tau, dt): momentum.py's ``update`` (its docstring has the recursion) */
static PyObject *Kernel_update(Kernel *self, PyObject *const *args, Py_ssize_t nargs) {
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "update(q, qd, tau, dt)");
        return NULL;
    }
    Py_ssize_t n = self->n;
    double q[n + 1], qd[n + 1], tau[n + 1];
    if (read_input(args[0], n, q, "q") < 0 || read_input(args[1], n, qd, "qd") < 0 ||
        read_input(args[2], n, tau, "tau") < 0)
        return NULL;
    double dt = PyFloat_AsDouble(args[3]);
    if (dt == -1.0 && PyErr_Occurred()) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) { /* the velocity step, while mjData still holds the previous reading */
        Py_ssize_t v = self->dofadr[i];
        self->step[v] = qd[i] - self->qvel[v];
    }
    self->mulm(self->m, self->d, self->mass_prev, self->step); /* M_{k−1}·Δq̇ */
    evaluate(self, q, qd);
    self->mulm(self->m, self->d, self->mass_now, self->step); /* M_k·Δq̇ */
    double gain = self->gain;
    double decay = 1.0 - gain * dt, half_k = 0.5 * gain, k_dt = gain * dt;
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t v = self->dofadr[i];
        double a = self->mass_now[v], b = self->mass_prev[v], g = self->bias[v], p = self->passive[v];
        double g0 = self->bias_prev[i], p0 = self->passive_prev[i];
        double r = decay * self->r[i] + half_k * (a + b) - k_dt * (tau[i] - 0.5 * (g - p + g0 - p0));
        self->r[i] = r;
        self->residual[i] = r;
        self->bias_prev[i] = g;
        self->passive_prev[i] = p;
    }
    Py_RETURN_NONE;
}

static PyMethodDef Kernel_methods[] = {
    {"reset", (PyCFunction)(void (*)(void))Kernel_reset, METH_FASTCALL, "reset(q, qd)"},
    {"update", (PyCFunction)(void (*)(void))Kernel_update, METH_FASTCALL, "update(q, qd, tau, dt)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject KernelType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "hild.dynamics._momentum.Kernel",
    .tp_basicsize = sizeof(Kernel),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "The momentum observer's update on MuJoCo's C functions (hild/dynamics/momentum.py).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Kernel_init,
    .tp_dealloc = (destructor)Kernel_dealloc,
    .tp_methods = Kernel_methods,
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_momentum",
                                    "The momentum observer's update, compiled.", -1, NULL};

PyMODINIT_FUNC PyInit__momentum(void) {
    if (PyType_Ready(&KernelType) < 0) return NULL;
    PyObject *mod = PyModule_Create(&module);
    if (mod == NULL) return NULL;
    Py_INCREF(&KernelType);
    if (PyModule_AddObject(mod, "Kernel", (PyObject *)&KernelType) < 0) {
        Py_DECREF(&KernelType);
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
