#!/bin/bash
# Odd-format variants of bad_records.py's ok.csv for the CLI (then: run_cli.sh OUTDIR).
#   benchmarks/outsider/odd_files.sh /tmp/s22o_cli/ok.csv /tmp/s22o_cli2
S=$1; D=$2; mkdir -p "$D"; cd "$D" || exit 1
sed 's/\r*$/\r/' $S > crlf.csv
printf '\xef\xbb\xbf' > bom.csv; cat $S >> bom.csv
sed '3s/.*/time [s], voltage [V], current [A], displacement [m], gauge [V]/' $S > spaced_header.csv
sed '3s/.*/time[us],voltage[kV],current[mA],displacement[nm],gauge[mV]/' $S > prefixes_wrong_scale.csv
sed 's/,/;/g' $S > semicolon.csv
awk 'NR<=3{print;next} NR%2==0{print}' $S > every_other_row.csv
awk 'NR<=3{print;next} NR<3000 || NR>3500 {print}' $S > gap_in_time.csv
sed '3s/.*/Time[s],Voltage[V],Current[A],Displacement[m],Gauge[V]/' $S > caps_header.csv
awk 'NR<=3{print;next}{print} END{print ""; print ""}' $S > trailing_blank.csv
(head -3 $S; tail -n +4 $S | head -2000) > two_seconds.csv
awk -F, 'NR<=3{print;next}{OFS=","; $4=""; print}' $S > empty_disp_cells.csv
sed '3s/displacement\[m\]/displacement[m],displacement[m]/; 4,$s/,\([^,]*\),\([^,]*\)$/,\1,\1,\2/' $S > dup_column.csv
sed '3s/.*/time[s],voltage[V],current[A],position[m],gauge[V]/' $S > unknown_disp_name.csv
sed '3s/current\[A\]/charge[C]/' $S > current_labelled_charge.csv
