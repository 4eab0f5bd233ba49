#version 330 core
out float out_z;
void main() { out_z = 1.0; }
