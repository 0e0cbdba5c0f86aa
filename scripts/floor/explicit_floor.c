// The explicit step's arithmetic in plain C, to measure this machine's scalar floor (docs/performance.md).
// gcc -O2 -march=native -o /tmp/explicit_floor scripts/floor/explicit_floor.c -lm && /tmp/explicit_floor 44
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
// same physics as the explicit kernel, on a synthetic region: nf free vertices, deg neighbours each
typedef struct { float x, y, z; } v3;
static double now(){ struct timespec t; clock_gettime(CLOCK_MONOTONIC,&t); return t.tv_sec+1e-9*t.tv_nsec; }
int main(int argc, char** argv){
  int n = 200, nf = atoi(argv[1]), deg = 6;
  v3 *q = malloc(n*sizeof(v3)), *qd = malloc(n*sizeof(v3)), *q2 = malloc(n*sizeof(v3)), *qd2 = malloc(n*sizeof(v3)), *qr = malloc(n*sizeof(v3));
  int *off = malloc((n+1)*sizeof(int)), *nb = malloc(n*deg*sizeof(int)), *fv = malloc(n*sizeof(int));
  float *ke = malloc(n*deg*4), *kd = malloc(n*deg*4), *L0 = malloc(n*deg*4), *im = malloc(n*4), *ka = malloc(n*4), *kda = malloc(n*4);
  srand(1);
  for(int i=0;i<n;i++){ q[i]=(v3){rand()/(float)RAND_MAX, rand()/(float)RAND_MAX, rand()/(float)RAND_MAX}; qr[i]=q[i]; qd[i]=(v3){0,0,0}; im[i]=1000; ka[i]=100; kda[i]=0.1; fv[i]=i; off[i]=i*deg;
    for(int k=0;k<deg;k++){ nb[i*deg+k]=rand()%n; ke[i*deg+k]=60; kd[i*deg+k]=0.02; L0[i*deg+k]=0.3; } }
  off[n]=n*deg;
  float dt = 1e-3f; int reps = 200000; double t0 = now();
  for(int r=0;r<reps;r++){
    for(int i=0;i<nf;i++){ int v=fv[i]; v3 x=q[v], u=qd[v];
      float fx=-(ka[v]*(x.x-qr[v].x)+kda[v]*u.x), fy=-(ka[v]*(x.y-qr[v].y)+kda[v]*u.y), fz=-(ka[v]*(x.z-qr[v].z)+kda[v]*u.z);
      for(int k=off[v];k<off[v+1];k++){ int j=nb[k]; float rx=q[j].x-x.x, ry=q[j].y-x.y, rz=q[j].z-x.z; float l=sqrtf(rx*rx+ry*ry+rz*rz);
        if(l>1e-9f){ float il=1.0f/l; float s=ke[k]*(l-L0[k]) + kd[k]*((qd[j].x-u.x)*rx+(qd[j].y-u.y)*ry+(qd[j].z-u.z)*rz)*il; fx+=s*il*rx; fy+=s*il*ry; fz+=s*il*rz; } }
      v3 u1={u.x+dt*fx*im[v], u.y+dt*fy*im[v], u.z+dt*fz*im[v]}; q2[v]=(v3){x.x+dt*u1.x, x.y+dt*u1.y, x.z+dt*u1.z}; qd2[v]=u1; }
    v3* t=q; q=q2; q2=t; t=qd; qd=qd2; qd2=t; }
  double el = now()-t0; printf("nf=%d: %.1f ns per step, %.1f ns per vertex (checksum %g)\n", nf, el/reps*1e9, el/reps/nf*1e9, q[3].x);
}
