% calibrate_tilt_table.m -- a user's own accelerometer calibration in Octave/MATLAB, no Python.
%
% Reads the recording.mat of an `imurig export tilt-table-quick --out DIR` folder, fits the
% accelerometers' FORWARD model per axis by least squares on per-position medians, and
% writes estimates.csv (name,value,std_error,unit) for `imurig score`.
%
% Forward model of axis i (q: reference specific force per position, m/s^2, segments struct):
%     V_i = s_i (a_i + b_i + k2_i a_i^2),  a = (I + M) q
%         ~ c1 q_i + c2 q_j + c3 q_k + c4 + c5 q_i^2
% so s_i = c1, M_ij = c2/c1, M_ik = c3/c1, b_i = c4/c1, k2_i = c5/c1; standard errors from
% the OLS covariance s^2 inv(X'X) by the delta method.
%
% Octave:  octave-cli calibrate_tilt_table.m DIR [estimates.csv]
% MATLAB:  set d and out below, then run the script.

args = {};
if exist('argv', 'builtin') || exist('argv')
  args = argv();
end
if numel(args) >= 1, d = args{1}; elseif ~exist('d', 'var'), d = '.'; end
if numel(args) >= 2, out = args{2}; elseif ~exist('out', 'var'), out = 'estimates.csv'; end

S = load(fullfile(d, 'recording.mat'));
t = S.time_s;
V = [S.channels.acc_x, S.channels.acc_y, S.channels.acc_z];          % volts, (n x 3)
sg = S.segments;
q = [sg.ref_f_x_m_s2, sg.ref_f_y_m_s2, sg.ref_f_z_m_s2];             % reference, m/s^2, (m x 3)
m = numel(sg.start_s);
Vw = zeros(m, 3);
for s = 1:m                                                          % window [start_s, stop_s)
  idx = t >= sg.start_s(s) & t < sg.stop_s(s);
  Vw(s, :) = median(V(idx, :), 1);
end

ax = 'xyz';
fid = fopen(out, 'w');
fprintf(fid, 'name,value,std_error,unit\n');
for i = 1:3
  o = setdiff(1:3, i); j = o(1); k = o(2);
  X = [q(:, i), q(:, j), q(:, k), ones(m, 1), q(:, i).^2];
  c = X \ Vw(:, i);
  r = Vw(:, i) - X * c;
  C = (r' * r) / (m - 5) * inv(X' * X);
  fprintf(fid, 'sensitivity_%s,%.17g,%.17g,V/(m/s^2)\n', ax(i), c(1), sqrt(C(1, 1)));
  names = {sprintf('misalignment_%s%s', ax(i), ax(j)), sprintf('misalignment_%s%s', ax(i), ax(k)), ...
           sprintf('bias_%s', ax(i)), sprintf('nonlinearity_%s', ax(i))};
  units = {'rad', 'rad', 'm/s^2', '1/(m/s^2)'};
  for p = 2:5                       % ratio c_p / c_1 and its delta-method standard error
    g = zeros(5, 1); g(p) = 1 / c(1); g(1) = -c(p) / c(1)^2;
    fprintf(fid, '%s,%.17g,%.17g,%s\n', names{p - 1}, c(p) / c(1), sqrt(g' * C * g), units{p - 1});
  end
end
fclose(fid);
fprintf('wrote %s: 15 parameters from %d positions\n', out, m);
