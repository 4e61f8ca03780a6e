/* A minimal FMI 2.0 Co-Simulation importer in C, no Python in the host process: what
   fmi_adapter, OMSimulator or Simulink do with an FMU, reduced to the calls (test_design_fmu.py).
   host BINARY GUID RESOURCES_URI STEPS: prints output_shaft.speed (value reference 9) after
   STEPS communication steps of 1 ms. */
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
typedef void *C; typedef unsigned int VR; typedef int S;
typedef void (*Logger)(void *, const char *, S, const char *, const char *, ...);
typedef struct { Logger logger; void *(*alloc)(size_t, size_t); void (*free)(void *);
                 void *step_finished; void *env; } Callbacks;
static void logger(void *e, const char *i, S s, const char *c, const char *m, ...) {
  va_list a; va_start(a, m); fprintf(stderr, "[%s %d] ", i, s); vfprintf(stderr, m, a);
  fprintf(stderr, "\n"); va_end(a); }
int main(int argc, char **argv) {
  void *so = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  if (!so) { printf("dlopen failed: %s\n", dlerror()); return 1; }
  C (*inst)(const char *, int, const char *, const char *, const Callbacks *, int, int) =
      dlsym(so, "fmi2Instantiate");
  S (*setup)(C, int, double, double, int, double) = dlsym(so, "fmi2SetupExperiment");
  S (*enter)(C) = dlsym(so, "fmi2EnterInitializationMode");
  S (*exit_)(C) = dlsym(so, "fmi2ExitInitializationMode");
  S (*step)(C, double, double, int) = dlsym(so, "fmi2DoStep");
  S (*get)(C, const VR *, size_t, double *) = dlsym(so, "fmi2GetReal");
  void (*free_)(C) = dlsym(so, "fmi2FreeInstance");
  Callbacks cb = {logger, calloc, free, NULL, NULL};
  C c = inst("host", 1, argv[2], argv[3], &cb, 0, 0);   /* 1 = fmi2CoSimulation */
  if (!c) { printf("fmi2Instantiate failed\n"); return 1; }
  setup(c, 0, 0.0, 0, 0, 0.0); enter(c);
  if (exit_(c) != 0) { printf("fmi2ExitInitializationMode failed\n"); return 1; }
  VR vr = 9; double w4 = 0; int n = atoi(argv[4]);
  for (int k = 0; k < n; k++) if (step(c, k * 1e-3, 1e-3, 1) != 0) { printf("doStep failed\n"); return 1; }
  get(c, &vr, 1, &w4); printf("output_shaft.speed after %d steps: %.17g\n", n, w4);
  free_(c); return 0; }
