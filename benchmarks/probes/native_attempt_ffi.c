/* The probe of benchmarks/probes/native_attempt_ffi.py: an error-controlled attempt of step doubling
   (whole step, two half steps with the hidden constraint's λ at each start, the estimate's three vector
   fields) as an XLA FFI handler over the native step's generated program (lobattodae.mechanics._native). */
#include "xla/ffi/api/c_api.h"
typedef struct { Solver half, whole; } AttemptState;   /* the Newton matrices and predictor histories */
static Tab TB;
void set_tableau(const double *tab) { memcpy(&TB, tab, sizeof TB); }
long attempt_state_doubles(void) { return (sizeof(AttemptState) + 7) / 8; }
#define BUF(i) ((XLA_FFI_Buffer*)frame->args.args[i])
#define RET(i) ((XLA_FFI_Buffer*)frame->rets.rets[i])
#ifndef A_TOL
#define A_TOL 1e-14
#endif
XLA_FFI_Error* lobattodae_native_attempt(XLA_FFI_CallFrame* frame) {
  if (frame->extension_start && frame->extension_start->type == XLA_FFI_Extension_Metadata) {
    XLA_FFI_Metadata_Extension* ext = (XLA_FFI_Metadata_Extension*)frame->extension_start;
    ext->metadata->api_version.major_version = XLA_FFI_API_MAJOR;
    ext->metadata->api_version.minor_version = XLA_FFI_API_MINOR;
    ext->metadata->traits = 0;
    return NULL;
  }
  if (frame->stage != XLA_FFI_ExecutionStage_EXECUTE) return NULL;
  const double t0 = *(double*)BUF(0)->data, h = *(double*)BUF(1)->data;
  const double *q0 = BUF(2)->data, *p0 = BUF(3)->data, *k = BUF(4)->data, *st_in = BUF(5)->data;
  const int extrapolate = *(int*)BUF(6)->data, maxit = *(int*)BUF(7)->data;
  const double *comp_in = BUF(8)->data; double *comp_out = RET(15)->data;
  double *q1 = RET(0)->data, *p1 = RET(1)->data, *l1 = RET(2)->data, *qw = RET(3)->data, *pw = RET(4)->data;
  double *fields = RET(5)->data; int *ints = RET(6)->data; double *resn = RET(7)->data, *drift = RET(8)->data;
  double *V = RET(9)->data, *W = RET(10)->data, *Lm = RET(11)->data, *qh = RET(12)->data, *ph = RET(13)->data;
  double *st_out = RET(14)->data;
  AttemptState *st = (AttemptState*)st_out;
  if ((const double*)st_out != st_in) memcpy(st_out, st_in, sizeof(AttemptState));
  long stats[2] = {0, 0};
  double lam1[NM], lw[NM], lh[NM], cw[2*NQ], rn = 0.0, hid_w[NM], hid_1[NM], v[NQ];
  model_lambda(t0, q0, p0, k, lam1);
  memcpy(cw, comp_in, sizeof cw); memcpy(comp_out, comp_in, sizeof cw);
  int whole_failed = 0, result = step(&st->whole, &TB, extrapolate, A_TOL, maxit, t0, h, q0, p0, lam1, cw, k, qw, pw, lw, &rn, stats);
  double res_max = rn;
  memset(V, 0, sizeof(double)*2*S*NQ); memset(W, 0, sizeof(double)*2*S*NQ); memset(Lm, 0, sizeof(double)*2*S*NM);
  if (result) { whole_failed = 1; memcpy(q1, q0, sizeof(double)*NQ); memcpy(p1, p0, sizeof(double)*NQ); memcpy(l1, lam1, sizeof(double)*NM);
                memcpy(qh, q0, sizeof(double)*NQ); memcpy(ph, p0, sizeof(double)*NQ); memcpy(qw, q0, sizeof(double)*NQ); memcpy(pw, p0, sizeof(double)*NQ); }
  else {
    double comp[2*NQ]; memcpy(comp, comp_in, sizeof comp);
    result = step(&st->half, &TB, extrapolate, A_TOL, maxit, t0, 0.5*h, q0, p0, lam1, comp, k, qh, ph, lh, &rn, stats);
    res_max = fmax(res_max, rn);
    if (!result) {
      memcpy(V, st->half.Vh, sizeof(double)*S*NQ); memcpy(W, st->half.Wh, sizeof(double)*S*NQ); memcpy(Lm, st->half.Lh, sizeof(double)*S*NM);
      double lmid[NM]; model_lambda(t0 + 0.5*h, qh, ph, k, lmid);
      result = step(&st->half, &TB, extrapolate, A_TOL, maxit, t0 + 0.5*h, 0.5*h, qh, ph, lmid, comp, k, q1, p1, l1, &rn, stats);
      res_max = fmax(res_max, rn);
      if (!result) {
        memcpy(V + S*NQ, st->half.Vh, sizeof(double)*S*NQ); memcpy(W + S*NQ, st->half.Wh, sizeof(double)*S*NQ); memcpy(Lm + S*NM, st->half.Lh, sizeof(double)*S*NM);
        memcpy(comp_out, comp, sizeof comp);
      }
    }
    if (result) { memcpy(q1, q0, sizeof(double)*NQ); memcpy(p1, p0, sizeof(double)*NQ); memcpy(l1, lam1, sizeof(double)*NM); }
  }
  model_lambda(t0 + h, qw, pw, k, hid_w); model_lambda(t0 + h, q1, p1, k, hid_1);
  model_fg(t0 + h, qw, pw, hid_w, k, fields, fields + NQ);
  model_fg(t0 + h, q1, p1, hid_1, k, fields + 2*NQ, fields + 3*NQ);
  model_fg(t0 + h, q1, p1, hid_w, k, fields + 4*NQ, fields + 5*NQ);
  (void)v;
  *drift = 0.0; for (int j = 0; j < NM; j++) *drift = fmax(*drift, fabs(l1[j] - hid_1[j]));
  ints[0] = result; ints[1] = (int)stats[0]; ints[2] = (int)stats[1]; ints[3] = whole_failed;
  *resn = res_max;
  return NULL;
}
