#!/usr/bin/env python3
"""Optimum of the paper's view-weighted L2 stretch on a hemisphere mapped as one chart.

    pip install numpy scipy
    python3 benches/hemisphere_optimum.py

V looks down on the pole (<N, V> = -cos(theta)), k = 1.2, so w = 1 / (k - cos(theta)): 5 at
the pole, 0.83 at the rim. By symmetry the optimal map is radial, rho(theta); the scale-free
energy (sum w L2^2 A3) * (sum A2) is minimised over rho' > 0 on 200 bands. Prints the texture
area per unit 3D area near the pole (cos > 0.9) over that near the rim (cos < 0.2): the most
any one-chart map can reach for this energy (1.26), which is why the atlas test asks for 1.18
(within 6% of it) and not the issue's 2.
"""
import numpy as np
from scipy.optimize import minimize
N=200; th=np.linspace(0,np.pi/2,N+1); k=1.2
def E(x):
    d=np.exp(x)                       # rho' >0 per segment
    rho=np.concatenate([[0],np.cumsum(d*(th[1]-th[0]))])
    tm=0.5*(th[1:]+th[:-1]); rm=0.5*(rho[1:]+rho[:-1])
    w=1/(k-np.cos(tm)); 
    l2=(1/d**2+np.sin(tm)**2/rm**2)/2
    SL=np.sum(w*l2*np.sin(tm)); SA=np.sum(rm*d)
    return SL*SA
r=minimize(E,np.zeros(N),method='L-BFGS-B',options={'maxiter':5000})
d=np.exp(r.x); rho=np.concatenate([[0],np.cumsum(d*(th[1]-th[0]))]); tm=0.5*(th[1:]+th[:-1]); rm=0.5*(rho[1:]+rho[:-1])
dens=rm*d/np.sin(tm)
cos=np.cos(tm)
print("pole", dens[cos>0.9].mean(), "rim", dens[cos<0.2].mean(), "ratio", dens[cos>0.9].mean()/dens[cos<0.2].mean())
