#!/bin/sh
# The 1e6 runs of docs/work_precision.md: per scene, the cheapest feedback-integrator run and the
# cheapest other run at t = 1e5 (make_docs.py long --t-final 1e5, the crossover table), to t = 1e6.
# Run from the repository root; resumes (long-1e+06.sqlite).
set -e
M="python benchmarks/make_docs.py long --t-final 1e6 --n-save 20000"
$M --only suslov --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only suslov --dts 4 --methods projection --schemes rk4
$M --only knife-edge --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only knife-edge --dts 8 --methods projection --schemes rk4
$M --only chaplygin --dts 8 --methods FI --gains 0.1 --schemes imex-rk4
$M --only chaplygin --dts 8 --methods no-feedback --schemes rk4
$M --only chaplygin-so2 --dts 8 --methods FI --gains 1 --schemes rk4
$M --only chaplygin-so2 --dts 8 --methods no-feedback --schemes rk4
$M --only roller-racer --dts 8 --methods FI --gains 1 --schemes rk4
$M --only roller-racer --dts 8 --methods projection --schemes rk4
$M --only heisenberg --dts 8 --methods FI-accurate --schemes rk4
$M --only heisenberg --dts 8 --methods projection --schemes rk4
$M --only oscillator --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only oscillator --dts 8 --methods projection --schemes rk4
$M --only nonreversible-oscillator --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only nonreversible-oscillator --dts 8 --methods projection --schemes rk4
$M --only nonreversible-contact-oscillator --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only nonreversible-contact-oscillator --dts 8 --methods projection --schemes rk4
$M --only rigid-body --dts 8 --methods FI-accurate --schemes imex-rk4
$M --only rigid-body --dts 8 --methods projection --schemes rk4
# the one-Newton-step projection, where it is the cheapest non-FI run at t = 1e5
$M --only oscillator --dts 8 --methods projection-1 --schemes rk4
$M --only nonreversible-oscillator --dts 8 --methods projection-1 --schemes rk4
$M --only nonreversible-contact-oscillator --dts 8 --methods projection-1 --schemes rk4
$M --only knife-edge --dts 8 --methods projection-1 --schemes rk4
$M --only rigid-body --dts 8 --methods projection-1 --schemes rk4
